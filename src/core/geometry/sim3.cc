#include "deblur_sr_mvs/core/geometry/sim3.h"

#include <string>

#include <Eigen/LU>
#include <Eigen/SVD>

#include "deblur_sr_mvs/core/common/errors.h"

namespace deblur_sr_mvs {

SE3 TransformPose(const Sim3& similarity, const SE3& T_world_cam) {
  return SE3(similarity.rotation * T_world_cam.rotation(),
             TransformPoint(similarity, T_world_cam.translation()));
}

Eigen::Vector3d TransformPoint(const Sim3& similarity, const Eigen::Vector3d& point) {
  return similarity.scale * (similarity.rotation * point) + similarity.translation;
}

Eigen::Vector3d InverseTransformPoint(const Sim3& similarity, const Eigen::Vector3d& target) {
  return similarity.rotation.transpose() * (target - similarity.translation) / similarity.scale;
}

void CheckCorrespondingPoints(const std::vector<Eigen::Vector3d>& source,
                              const std::vector<Eigen::Vector3d>& target, const char* what) {
  if (source.size() != target.size()) {
    throw InputError(std::string(what) + ": " + std::to_string(source.size()) + " estimated vs " +
                     std::to_string(target.size()) + " reference points");
  }
  if (source.size() < 3) {
    throw InputError(std::string(what) + ": needs at least 3 corresponding points, got " +
                     std::to_string(source.size()));
  }
  for (std::size_t i = 0; i < source.size(); ++i) {
    if (!source[i].allFinite() || !target[i].allFinite()) {
      throw InputError(std::string(what) + ": point " + std::to_string(i) + " is not finite");
    }
  }
}

Sim3 UmeyamaAlignment(const std::vector<Eigen::Vector3d>& source, const std::vector<Eigen::Vector3d>& target,
                      bool with_scale) {
  CheckCorrespondingPoints(source, target, "Umeyama alignment");
  const double n = static_cast<double>(source.size());
  Eigen::Vector3d mean_source = Eigen::Vector3d::Zero();
  Eigen::Vector3d mean_target = Eigen::Vector3d::Zero();
  for (std::size_t i = 0; i < source.size(); ++i) {
    mean_source += source[i];
    mean_target += target[i];
  }
  mean_source /= n;
  mean_target /= n;

  // Cross-covariance Sigma = 1/n sum (y - mu_y)(x - mu_x)^T and the source
  // variance (Umeyama 1991, eqs. 36-42).
  Eigen::Matrix3d sigma = Eigen::Matrix3d::Zero();
  double variance_source = 0.0;
  for (std::size_t i = 0; i < source.size(); ++i) {
    const Eigen::Vector3d x = source[i] - mean_source;
    sigma += (target[i] - mean_target) * x.transpose();
    variance_source += x.squaredNorm();
  }
  sigma /= n;
  variance_source /= n;
  if (!(variance_source > 0.0)) {
    throw InputError("Umeyama alignment: all source points coincide");
  }

  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(sigma, Eigen::ComputeFullU | Eigen::ComputeFullV);
  // S = diag(1, 1, -1) when det(U) det(V) < 0 keeps R a rotation (no reflection).
  Eigen::Vector3d s = Eigen::Vector3d::Ones();
  if (svd.matrixU().determinant() * svd.matrixV().determinant() < 0.0) s(2) = -1.0;

  Sim3 result;
  result.rotation = svd.matrixU() * s.asDiagonal() * svd.matrixV().transpose();
  result.scale = with_scale ? svd.singularValues().dot(s) / variance_source : 1.0;
  result.translation = mean_target - result.scale * result.rotation * mean_source;
  return result;
}

}  // namespace deblur_sr_mvs
