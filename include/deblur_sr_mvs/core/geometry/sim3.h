// Similarity transforms (Sim(3)) and their least-squares estimation from
// corresponding points: the alignment of a monocular trajectory (arbitrary
// scale) onto another one.
#pragma once

#include <vector>

#include <Eigen/Core>

#include "deblur_sr_mvs/core/geometry/se3.h"

namespace deblur_sr_mvs {

// Similarity transform target ~= scale * rotation * source + translation.
struct Sim3 {
  double scale = 1.0;
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();
};

// T_world_cam of a camera after a similarity of the world (the camera
// keeps its view; its centre moves with the world).
SE3 TransformPose(const Sim3& similarity, const SE3& T_world_cam);

// scale * rotation * point + translation: `point` carried into the target
// frame (e.g. an estimated camera centre aligned to the ground truth).
Eigen::Vector3d TransformPoint(const Sim3& similarity, const Eigen::Vector3d& point);

// The source point that `similarity` maps to `target` (TransformPoint's inverse):
// rotation^T (target - translation) / scale (e.g. a pose prior's camera
// centre carried back into the estimate's world).
Eigen::Vector3d InverseTransformPoint(const Sim3& similarity, const Eigen::Vector3d& target);

// Umeyama (1991) least-squares alignment of corresponding points.
// Needs >= 3 corresponding points so that the rotation is determined (fewer,
// a size mismatch, non-finite or coincident source points: InputError).
Sim3 UmeyamaAlignment(const std::vector<Eigen::Vector3d>& source, const std::vector<Eigen::Vector3d>& target,
                      bool with_scale);

// Throws InputError (naming `what`) unless source and target have the same
// size, at least 3 points, and every point is finite.
void CheckCorrespondingPoints(const std::vector<Eigen::Vector3d>& source,
                              const std::vector<Eigen::Vector3d>& target, const char* what);

}  // namespace deblur_sr_mvs
