// Initialisation of poses and LR depths (paper Sec. optInitialization).
//
// Stages (timed in InitialStructure::summary):
//  1. tracking: Shi-Tomasi corners followed frame to frame by OpenCV's
//     pyramidal Lucas-Kanade with a forward-backward check. Consecutive
//     frames of a smoothly moving camera carry nearly the same blur, so
//     brightness constancy holds between them far better than descriptor
//     repeatability does on tiny, smeared LR frames.
//  2. two-view: the nearest pair of frames whose matches leave displacement
//     that no rotation explains (RankInitialPairs; frames 0-1 when they have
//     it, NoParallaxError when no pair has), then essential matrix (RANSAC)
//     and recoverPose on it, the paper's SfM step, plus a pure-translation
//     start; both refined with a rotation prior that settles the rotation /
//     translation ambiguity of narrow fields of view (RotationPrior); checks
//     features, inliers and parallax.
//  3. poses: triangulation, PnP (RANSAC) of every other frame (between the
//     pair, then forward, then backward), then a bundle adjustment of all
//     poses and points (Ceres) with the pair's first camera fixed and its
//     baseline held at 1 by a sphere manifold. Tracks on blurred frames
//     follow blur centroids, so these are mid-exposure poses; they are moved
//     to the shutter close t_c along eq:interpolatingP, world = camera 0 at
//     t_c.
//  4. depths: eq:initializationScene per frame, coarse to fine: a plane
//     sweep over inverse depth on a half-size pyramid level, of blur-aware L1
//     patch costs (Psi_s o B_t vs Psi_t o B_s from scale-1 capture operators,
//     each image read at the point's blur centroid so that the depth lands on
//     the t_c grid) against up to two neighbours per side, TV-L1 with the
//     edge weight g_t (eq:regularizingTerm) by the DTAM alternation, then a
//     full-size pass with operators re-built from that depth, a narrow
//     per-pixel sweep and sub-plane refinement. Last the output scale: the
//     median LR depth of the window is 1 (NormaliseGauge,
//     docs/file_formats.md#monocular-scale).
// EstimateRotationOnlyMotion shares stage 1 and the move to t_c: the
// orientations of a camera that only turns, fitted to the tracks' rays.
#include "deblur_sr_mvs/core/estimation/initializer.h"

#include <omp.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <limits>
#include <memory>
#include <optional>
#include <sstream>
#include <utility>

#include <ceres/ceres.h>
#include <ceres/rotation.h>
#include <Eigen/Dense>
#include <boost/math/distributions/normal.hpp>
#include <boost/math/distributions/students_t.hpp>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/video/tracking.hpp>

#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/common/grid_minimum.h"
#include "deblur_sr_mvs/core/common/options_check.h"
#include "deblur_sr_mvs/core/common/runtime.h"
#include "deblur_sr_mvs/core/geometry/pose_prior.h"
#include "deblur_sr_mvs/core/geometry/sim3.h"
#include "deblur_sr_mvs/core/geometry/visibility.h"
#include "deblur_sr_mvs/core/geometry/warp.h"
#include "deblur_sr_mvs/core/imaging/capture_operator.h"
#include "deblur_sr_mvs/core/imaging/image_ops.h"

namespace deblur_sr_mvs {
namespace {

std::string Format(const char* format, double a = 0, double b = 0, double c = 0, double d = 0, double e = 0,
                   double f = 0) {
  char buffer[512];
  std::snprintf(buffer, sizeof(buffer), format, a, b, c, d, e, f);
  return buffer;
}

double Median(std::vector<double> values) {
  if (values.empty()) return 0.0;
  const size_t middle = values.size() / 2;
  std::nth_element(values.begin(), values.begin() + middle, values.end());
  return values[middle];
}

double Percentile(std::vector<double> values, double fraction) {
  if (values.empty()) return 0.0;
  const size_t index = std::min(values.size() - 1, static_cast<size_t>(fraction * (values.size() - 1) + 0.5));
  std::nth_element(values.begin(), values.begin() + index, values.end());
  return values[index];
}

// ------------------------------------------------------------------ tracking

// Lucas-Kanade settings (cv::calcOpticalFlowPyrLK) shared by the forward and
// backward passes. OpenCV reads 8-bit images: its residual is in 8-bit
// intensity units and its minimum eigenvalue is that of the mean structure
// tensor of Scharr derivatives (32x the central difference, 8-bit units)
// scaled by 2^-10.
struct LucasKanadeSettings {
  cv::Size window;
  int max_level = 0;  // 0-based: klt_levels - 1
  cv::TermCriteria criteria;
  double min_eigen = 0.0;  // OpenCV's minEigThreshold
  float max_error = 0.0f;  // mean |difference| (8-bit units) of a kept match
  float margin = 0.0f;     // a tracked point keeps this far (px) from the border
};

LucasKanadeSettings MakeLucasKanadeSettings(const InitializerOptions& options) {
  // Mean-structure-tensor eigenvalue floor on [0,1] images with central
  // differences, in OpenCV's units: (255 * 32)^2 / 2^20 = 255^2 / 1024.
  constexpr double kMinEigen01 = 1e-4;
  LucasKanadeSettings settings;
  const int side = 2 * options.klt_window_radius_px + 1;
  settings.window = cv::Size(side, side);
  settings.max_level = options.klt_levels - 1;
  settings.criteria = cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 20, 0.01);
  settings.min_eigen = kMinEigen01 * 255.0 * 255.0 / 1024.0;
  settings.max_error = static_cast<float>(options.klt_max_residual * 255.0);
  settings.margin = static_cast<float>(options.klt_window_radius_px) * 0.5f;
  return settings;
}

// A feature followed over consecutive frames [first_frame, first_frame + n).
struct Track {
  int first_frame = 0;
  std::vector<cv::Point2f> points;
  int point_id = -1;  // index into the 3D points, -1 until triangulated
  int LastFrame() const { return first_frame + static_cast<int>(points.size()) - 1; }
  bool Sees(int frame) const { return frame >= first_frame && frame <= LastFrame(); }
  const cv::Point2f& At(int frame) const { return points[frame - first_frame]; }
};

struct TrackingResult {
  std::vector<Track> tracks;
  std::vector<int> detected;  // new corners per frame
  std::vector<int> alive;     // tracks followed into each frame from the previous one
};

// Whether OpenCV's match of one point is kept: tracked, small residual, and
// at least `margin` inside the image.
bool GoodMatch(uchar status, float error, const cv::Point2f& point, const cv::Size& size,
               const LucasKanadeSettings& settings) {
  return status != 0 && error <= settings.max_error && point.x >= settings.margin &&
         point.y >= settings.margin && point.x <= size.width - 1 - settings.margin &&
         point.y <= size.height - 1 - settings.margin;
}

// Follows the active tracks from frame t - 1 into t: a forward pass started
// from each track's last velocity, a backward pass from the forward result,
// and a forward-backward check. Tracks that survive get their point in t and
// stay active.
void FollowTracks(const std::vector<cv::Mat>& previous_pyramid, const std::vector<cv::Mat>& pyramid,
                  const cv::Size& size, const LucasKanadeSettings& settings, double max_forward_backward_px,
                  std::vector<int>* active, std::vector<Track>* tracks) {
  if (active->empty()) return;
  const size_t count = active->size();
  std::vector<cv::Point2f> from(count), forward(count);
  for (size_t a = 0; a < count; ++a) {
    const Track& track = (*tracks)[(*active)[a]];
    from[a] = track.points.back();
    cv::Point2f guess(0.0f, 0.0f);
    if (track.points.size() >= 2) guess = from[a] - track.points[track.points.size() - 2];
    forward[a] = from[a] + guess;
  }
  std::vector<uchar> forward_status, backward_status;
  std::vector<float> forward_error, backward_error;
  cv::calcOpticalFlowPyrLK(previous_pyramid, pyramid, from, forward, forward_status, forward_error,
                           settings.window, settings.max_level, settings.criteria,
                           cv::OPTFLOW_USE_INITIAL_FLOW, settings.min_eigen);
  std::vector<cv::Point2f> backward = from;
  cv::calcOpticalFlowPyrLK(pyramid, previous_pyramid, forward, backward, backward_status, backward_error,
                           settings.window, settings.max_level, settings.criteria,
                           cv::OPTFLOW_USE_INITIAL_FLOW, settings.min_eigen);
  const double max_squared = max_forward_backward_px * max_forward_backward_px;
  std::vector<int> still_active;
  for (size_t a = 0; a < count; ++a) {
    if (!GoodMatch(forward_status[a], forward_error[a], forward[a], size, settings) ||
        !GoodMatch(backward_status[a], backward_error[a], backward[a], size, settings)) {
      continue;
    }
    const cv::Point2f error = backward[a] - from[a];
    if (error.dot(error) > max_squared) continue;
    (*tracks)[(*active)[a]].points.push_back(forward[a]);
    still_active.push_back((*active)[a]);
  }
  active->swap(still_active);
}

// Starts new tracks in frame t at Shi-Tomasi corners away from the active
// ones, up to options.max_features active tracks.
void DetectNewTracks(const cv::Mat& gray8, int t, const InitializerOptions& options, std::vector<int>* active,
                     TrackingResult* result) {
  const float min_distance = static_cast<float>(options.min_feature_distance_px);
  cv::Mat mask(gray8.size(), CV_8UC1, cv::Scalar(255));
  for (int index : *active) {
    cv::circle(mask, result->tracks[index].points.back(), static_cast<int>(min_distance + 0.5f),
               cv::Scalar(0), -1);
  }
  const int wanted = options.max_features - static_cast<int>(active->size());
  if (wanted <= 0) return;
  std::vector<cv::Point2f> corners;
  cv::goodFeaturesToTrack(gray8, corners, wanted, options.feature_quality, min_distance, mask,
                          options.feature_block_size);
  const float border = static_cast<float>(options.klt_window_radius_px);
  for (const cv::Point2f& corner : corners) {
    if (corner.x < border || corner.y < border || corner.x > gray8.cols - 1 - border ||
        corner.y > gray8.rows - 1 - border) {
      continue;
    }
    Track track;
    track.first_frame = t;
    track.points.push_back(corner);
    active->push_back(static_cast<int>(result->tracks.size()));
    result->tracks.push_back(track);
    ++result->detected[t];
  }
}

// Shi-Tomasi corners followed frame to frame by pyramidal Lucas-Kanade with a
// forward-backward check, replenished in every frame but the last.
TrackingResult TrackFeatures(const std::vector<cv::Mat>& gray, const InitializerOptions& options,
                             int threads) {
  const int num_frames = static_cast<int>(gray.size());
  const LucasKanadeSettings settings = MakeLucasKanadeSettings(options);
  std::vector<cv::Mat> gray8(num_frames);
  std::vector<std::vector<cv::Mat>> pyramids(num_frames);
#pragma omp parallel for schedule(dynamic, 1) num_threads(threads)
  for (int t = 0; t < num_frames; ++t) {
    gray[t].convertTo(gray8[t], CV_8U, 255.0);
    cv::buildOpticalFlowPyramid(gray8[t], pyramids[t], settings.window, settings.max_level);
  }
  TrackingResult result;
  result.detected.assign(num_frames, 0);
  result.alive.assign(num_frames, 0);
  std::vector<int> active;  // tracks that reached the current frame
  for (int t = 0; t < num_frames; ++t) {
    if (t > 0) {
      FollowTracks(pyramids[t - 1], pyramids[t], gray[t].size(), settings, options.max_forward_backward_px,
                   &active, &result.tracks);
    }
    result.alive[t] = static_cast<int>(active.size());
    if (t + 1 < num_frames) DetectNewTracks(gray8[t], t, options, &active, &result);
  }
  return result;
}

// ------------------------------------------------------------- geometry

// A frame's pose as T_cam_world in angle-axis + translation, Ceres' layout.
struct PoseParameters {
  double rotation[3] = {0.0, 0.0, 0.0};
  double translation[3] = {0.0, 0.0, 0.0};
};

PoseParameters ToParameters(const SE3& T_cam_world) {
  PoseParameters parameters;
  const Eigen::AngleAxisd angle_axis(T_cam_world.rotation());
  const Eigen::Vector3d rotation = angle_axis.angle() * angle_axis.axis();
  for (int k = 0; k < 3; ++k) {
    parameters.rotation[k] = rotation[k];
    parameters.translation[k] = T_cam_world.translation()[k];
  }
  return parameters;
}

// The rotation matrix of an angle-axis vector (the identity near 0).
Eigen::Matrix3d RotationFromAngleAxis(const Eigen::Vector3d& rotation) {
  const double angle = rotation.norm();
  return angle < 1e-15 ? Eigen::Matrix3d::Identity()
                       : Eigen::Matrix3d(Eigen::AngleAxisd(angle, rotation / angle).toRotationMatrix());
}

SE3 FromParameters(const PoseParameters& parameters) {
  return SE3(RotationFromAngleAxis(Eigen::Vector3d(parameters.rotation)),
             Eigen::Vector3d(parameters.translation));
}

SE3 FromOpenCv(const cv::Mat& rvec, const cv::Mat& tvec) {
  cv::Mat R;
  cv::Rodrigues(rvec, R);
  Eigen::Matrix3d rotation;
  Eigen::Vector3d translation;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) rotation(r, c) = R.at<double>(r, c);
    translation[r] = tvec.at<double>(r);
  }
  return SE3(rotation, translation);
}

void ToOpenCv(const SE3& T_cam_world, cv::Mat* rvec, cv::Mat* tvec) {
  cv::Mat R(3, 3, CV_64F);
  *tvec = cv::Mat(3, 1, CV_64F);
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) R.at<double>(r, c) = T_cam_world.rotation()(r, c);
    tvec->at<double>(r) = T_cam_world.translation()[r];
  }
  cv::Rodrigues(R, *rvec);
}

// Levenberg-Marquardt (dense Schur) on `threads` threads, silent, with the
// bundle-adjustment iteration cap: the solver of the two-view refinement and
// the bundle adjustment.
ceres::Solver::Summary SolveQuietly(const InitializerOptions& options, int threads, ceres::Problem* problem) {
  ceres::Solver::Options solver_options;
  solver_options.linear_solver_type = ceres::DENSE_SCHUR;
  solver_options.max_num_iterations = options.ba_max_iterations;
  solver_options.num_threads = threads;
  solver_options.logging_type = ceres::SILENT;
  ceres::Solver::Summary summary;
  ceres::Solve(solver_options, problem, &summary);
  return summary;
}

struct ReprojectionResidual {
  ReprojectionResidual(const cv::Point2f& observed, const PinholeCamera& camera)
      : u(observed.x), v(observed.y), fx(camera.fx), fy(camera.fy), cx(camera.cx), cy(camera.cy) {}
  template <typename T>
  bool operator()(const T* rotation, const T* translation, const T* point_world, T* residual) const {
    T p[3];
    ceres::AngleAxisRotatePoint(rotation, point_world, p);
    for (int k = 0; k < 3; ++k) p[k] += translation[k];
    if (p[2] < T(1e-9)) p[2] = T(1e-9);
    residual[0] = T(fx) * p[0] / p[2] + T(cx) - T(u);
    residual[1] = T(fy) * p[1] / p[2] + T(cy) - T(v);
    return true;
  }
  double u, v, fx, fy, cx, cy;
};

// Reprojection error (px) of a world point in a camera; infinity when behind.
double ReprojectionError(const PinholeCamera& camera, const SE3& T_cam_world,
                         const Eigen::Vector3d& point_world, const cv::Point2f& observed) {
  const Eigen::Vector3d p = T_cam_world * point_world;
  if (!(p.z() > 1e-9)) return std::numeric_limits<double>::infinity();
  const Eigen::Vector2d projected = camera.Project(p);
  return std::hypot(projected.x() - observed.x, projected.y() - observed.y);
}

// Linear (DLT) triangulation from every observation of the track in a frame
// with a known pose.
bool TriangulateTrack(const PinholeCamera& camera, const std::vector<SE3>& T_cam_world,
                      const std::vector<char>& has_pose, const Track& track, int last_frame,
                      Eigen::Vector3d* point_world) {
  std::vector<Eigen::Vector3d> rays;
  std::vector<SE3> cameras;
  for (int frame = track.first_frame; frame <= std::min(track.LastFrame(), last_frame); ++frame) {
    if (!has_pose[frame]) continue;
    rays.push_back(camera.Ray(track.At(frame).x, track.At(frame).y));
    cameras.push_back(T_cam_world[frame]);
  }
  return TriangulateRays(rays, cameras, point_world);
}

// Image displacement (px) of a track between frames a and b that rotation
// alone does not explain: the parallax that carries depth information.
double TranslationalParallax(const PinholeCamera& camera, const SE3& T_b_a, const cv::Point2f& pa,
                             const cv::Point2f& pb) {
  const Eigen::Vector3d rotated = T_b_a.rotation() * camera.Ray(pa.x, pa.y);
  if (!(rotated.z() > 1e-9)) return 0.0;
  const Eigen::Vector2d predicted = camera.Project(rotated);
  return std::hypot(predicted.x() - pb.x, predicted.y() - pb.y);
}

struct SparseStructure {
  // Gauge of the bundle adjustment: camera `reference` fixed (the world), the
  // centre of `baseline_frame` 1 unit from it (the two-view pair).
  int reference = 0;
  int baseline_frame = 1;
  std::vector<SE3> T_cam_world;
  std::vector<Eigen::Vector3d> points_world;
  std::vector<char> point_inlier;
  // The RotationPrior's turn rate kappa (inverse fixation distance, 1 / pair
  // baselines): held at 0 (no turn expected) or fitted (SelectFixationTurn).
  double turn_rate = 0.0;
  bool fit_turn_rate = false;
  // Soft constraints on the camera centres (AdjustToPosePrior): per frame
  // its pose prior's centre at mid-exposure in the structure's world, none
  // where the prior has none or disagrees. Empty: no prior, and the gauge
  // holds the pair's baseline at 1; else the prior fixes the scale.
  std::vector<std::optional<Eigen::Vector3d>> prior_centres;
  double prior_sigma = 0.0;  // their standard deviation per axis (world units)
  // The same frames' prior orientations R_cam_world, and their standard
  // deviation (radians); 0: not used.
  std::vector<Eigen::Matrix3d> prior_orientations;
  double prior_rotation_sigma = 0.0;
  std::vector<std::string> log;
};

// Triangulates the tracks without a point that `frame` (just posed) sees:
// from all their posed frames, when the posed frame farthest from `frame` in
// the track leaves at least min_triangulation_parallax_px of displacement
// that the rotation does not explain, and the point reprojects into every
// posed frame of the track.
void TriangulateNewPoints(const PinholeCamera& camera, const InitializerOptions& options, int frame,
                          const std::vector<char>& has_pose, std::vector<Track>* tracks,
                          SparseStructure* structure) {
  for (Track& track : *tracks) {
    if (track.point_id >= 0 || !track.Sees(frame)) continue;
    int farthest = -1;
    for (int f = track.first_frame; f <= track.LastFrame(); ++f) {
      if (f != frame && has_pose[f] && (farthest < 0 || std::abs(f - frame) > std::abs(farthest - frame))) {
        farthest = f;
      }
    }
    if (farthest < 0) continue;
    const SE3 T_b_a = structure->T_cam_world[frame] * structure->T_cam_world[farthest].Inverse();
    if (TranslationalParallax(camera, T_b_a, track.At(farthest), track.At(frame)) <
        options.min_triangulation_parallax_px) {
      continue;
    }
    Eigen::Vector3d point;
    if (!TriangulateTrack(camera, structure->T_cam_world, has_pose, track, track.LastFrame(), &point))
      continue;
    bool good = true;
    for (int f = track.first_frame; f <= track.LastFrame() && good; ++f) {
      if (!has_pose[f]) continue;
      good = ReprojectionError(camera, structure->T_cam_world[f], point, track.At(f)) <=
             options.ransac_threshold_px * 2.0;
    }
    if (!good) continue;
    track.point_id = static_cast<int>(structure->points_world.size());
    structure->points_world.push_back(point);
    structure->point_inlier.push_back(1);
  }
}

cv::Mat CameraMatrix(const PinholeCamera& camera) {
  return (cv::Mat_<double>(3, 3) << camera.fx, 0.0, camera.cx, 0.0, camera.fy, camera.cy, 0.0, 0.0, 1.0);
}

// The rotation nearest to M in the Frobenius norm (SVD, determinant +1).
Eigen::Matrix3d NearestRotation(const Eigen::Matrix3d& M) {
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(M, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d D = Eigen::Matrix3d::Identity();
  D(2, 2) = (svd.matrixU() * svd.matrixV().transpose()).determinant() < 0.0 ? -1.0 : 1.0;
  return svd.matrixU() * D * svd.matrixV().transpose();
}

// Kabsch: the rotation R minimising sum |b1_k - R b0_k|^2 over the used unit
// rays.
Eigen::Matrix3d KabschRotation(const std::vector<Eigen::Vector3d>& b0, const std::vector<Eigen::Vector3d>& b1,
                               const std::vector<char>& use) {
  Eigen::Matrix3d H = Eigen::Matrix3d::Zero();
  for (size_t k = 0; k < b0.size(); ++k) {
    if (use[k]) H += b1[k] * b0[k].transpose();
  }
  return NearestRotation(H);
}

// Image distance (px) between x1 and the pixel x0 moved by the rotation R
// (ray1 ~ R ray0); a large value when the rotated ray points backwards.
double RotationResidual(const PinholeCamera& camera, const Eigen::Matrix3d& R, const cv::Point2f& x0,
                        const cv::Point2f& x1) {
  const Eigen::Vector3d rotated = R * camera.Ray(x0.x, x0.y);
  return rotated.z() > 1e-9 ? (camera.Project(rotated) - Eigen::Vector2d(x1.x, x1.y)).norm() : 1e9;
}

void UnitRays(const PinholeCamera& camera, const std::vector<cv::Point2f>& points,
              std::vector<Eigen::Vector3d>* rays) {
  rays->resize(points.size());
  for (size_t k = 0; k < points.size(); ++k) (*rays)[k] = camera.Ray(points[k].x, points[k].y).normalized();
}

// Rotation-only fit of matched pixels (Kabsch on bearings, refit on the
// better half): the median residual (px) is the parallax that no camera
// rotation explains, i.e. what translation contributes.
double RotationFreeParallax(const PinholeCamera& camera, const std::vector<cv::Point2f>& points0,
                            const std::vector<cv::Point2f>& points1) {
  const int n = static_cast<int>(points0.size());
  std::vector<Eigen::Vector3d> b0, b1;
  UnitRays(camera, points0, &b0);
  UnitRays(camera, points1, &b1);
  std::vector<char> use(n, 1);
  std::vector<double> residuals(n);
  for (int round = 0; round < 3; ++round) {
    const Eigen::Matrix3d R = KabschRotation(b0, b1, use);  // b1 ~ R b0
    for (int k = 0; k < n; ++k) residuals[k] = RotationResidual(camera, R, points0[k], points1[k]);
    const double median = Median(residuals);
    for (int k = 0; k < n; ++k) use[k] = residuals[k] <= median;
  }
  return Median(residuals);
}

// A pure rotation fitted to matched pixels.
struct RotationFit {
  Eigen::Matrix3d R_1_0 = Eigen::Matrix3d::Identity();  // ray1 ~ R_1_0 ray0
  int inliers = 0;
  double rms_px = 0.0;  // of the inliers
};

// Robust rotation between two frames: RANSAC over pairs of matches (two rays
// fix a rotation), inliers within threshold_px of where the rotation moves
// them, then Kabsch on the inliers, re-selected and refitted twice.
RotationFit FitRotationRansac(const PinholeCamera& camera, const std::vector<cv::Point2f>& points0,
                              const std::vector<cv::Point2f>& points1, double threshold_px) {
  const int n = static_cast<int>(points0.size());
  std::vector<Eigen::Vector3d> b0, b1;
  UnitRays(camera, points0, &b0);
  UnitRays(camera, points1, &b1);
  std::vector<char> use(n, 0);
  cv::RNG rng(0x5eed);  // fixed: the same frames give the same rotation
  RotationFit fit;
  fit.inliers = -1;
  for (int iteration = 0; iteration < 200 && n >= 2; ++iteration) {
    const int i = rng.uniform(0, n);
    const int j = rng.uniform(0, n);
    if (i == j || b0[i].cross(b0[j]).norm() < 1e-3) continue;
    std::fill(use.begin(), use.end(), 0);
    use[i] = use[j] = 1;
    const Eigen::Matrix3d R = KabschRotation(b0, b1, use);
    int count = 0;
    for (int k = 0; k < n; ++k) count += RotationResidual(camera, R, points0[k], points1[k]) <= threshold_px;
    if (count > fit.inliers) {
      fit.inliers = count;
      fit.R_1_0 = R;
    }
  }
  for (int round = 0; round < 3; ++round) {
    double squares = 0.0;
    fit.inliers = 0;
    for (int k = 0; k < n; ++k) {
      const double residual = RotationResidual(camera, fit.R_1_0, points0[k], points1[k]);
      use[k] = residual <= threshold_px;
      fit.inliers += use[k];
      squares += use[k] ? residual * residual : 0.0;
    }
    fit.rms_px = std::sqrt(squares / std::max(1, fit.inliers));
    if (round < 2 && fit.inliers >= 2) fit.R_1_0 = KabschRotation(b0, b1, use);
  }
  return fit;
}

// Reprojection into camera 1 of the point at inverse depth rho on the ray of
// pixel x0 of camera 0: p1 ~ R ray0 + rho t (no division by rho, so points
// at infinity are fine).
struct TwoViewResidual {
  TwoViewResidual(const Eigen::Vector3d& ray0_in, const cv::Point2f& observed, const PinholeCamera& camera)
      : ray0(ray0_in),
        u(observed.x),
        v(observed.y),
        fx(camera.fx),
        fy(camera.fy),
        cx(camera.cx),
        cy(camera.cy) {}
  template <typename T>
  bool operator()(const T* rotation, const T* translation, const T* inverse_depth, T* residual) const {
    const T ray[3] = {T(ray0.x()), T(ray0.y()), T(ray0.z())};
    T p[3];
    ceres::AngleAxisRotatePoint(rotation, ray, p);
    for (int k = 0; k < 3; ++k) p[k] += inverse_depth[0] * translation[k];
    if (p[2] < T(1e-9)) p[2] = T(1e-9);
    residual[0] = T(fx) * p[0] / p[2] + T(cx) - T(u);
    residual[1] = T(fy) * p[1] / p[2] + T(cy) - T(v);
    return true;
  }
  Eigen::Vector3d ray0;
  double u, v, fx, fy, cx, cy;
};

// Prior on the rotation between two consecutive cameras a, b: f |log R_b R_a^T
// + omega| / sigma, with omega = kappa (Delta x z) the turn of a camera that
// moves by Delta (b's centre in camera a) while it keeps looking at the point
// at distance 1 / kappa on its optical axis (kappa = 0: towards no rotation).
// With a narrow field of view (the Middlebury views span ~13 degrees) a small
// rotation and a sideways translation move the image almost identically; the
// reconstructions along that valley fit the tracks to far below their noise
// (bas-relief ambiguity) but bend the inverse depths affinely. The valley is
// one turn per unit of sideways motion for the whole window, i.e. kappa: the
// prior picks the member that turns as kappa says (SelectFixationTurn decides
// kappa) and is negligible where the rotation is observable (wide fields of
// view).
struct RotationPrior {
  RotationPrior(double focal_px, double sigma_px) : scale(focal_px / sigma_px) {}
  template <typename T>
  bool operator()(const T* rotation_a, const T* translation_a, const T* rotation_b, const T* translation_b,
                  const T* turn_rate, T* residual) const {
    // R_b R_a^T as quaternions.
    T qa[4], qb[4], qa_inverse[4], q[4];
    ceres::AngleAxisToQuaternion(rotation_a, qa);
    ceres::AngleAxisToQuaternion(rotation_b, qb);
    qa_inverse[0] = qa[0];
    for (int k = 1; k < 4; ++k) qa_inverse[k] = -qa[k];
    ceres::QuaternionProduct(qb, qa_inverse, q);
    T angle_axis[3];
    ceres::QuaternionToAngleAxis(q, angle_axis);
    // Delta = R_a c_b + t_a with c_b = -R_b^T t_b.
    const T inverse_b[3] = {-rotation_b[0], -rotation_b[1], -rotation_b[2]};
    const T minus_t_b[3] = {-translation_b[0], -translation_b[1], -translation_b[2]};
    T centre_b[3], delta[3];
    ceres::AngleAxisRotatePoint(inverse_b, minus_t_b, centre_b);
    ceres::AngleAxisRotatePoint(rotation_a, centre_b, delta);
    for (int k = 0; k < 3; ++k) delta[k] += translation_a[k];
    // R_b R_a^T = exp(-omega): the turn to the left of a camera moving right.
    residual[0] = T(scale) * (angle_axis[0] + turn_rate[0] * delta[1]);
    residual[1] = T(scale) * (angle_axis[1] - turn_rate[0] * delta[0]);
    residual[2] = T(scale) * angle_axis[2];
    return true;
  }
  double scale;
};

// Same prior for frame b of the two-view pair against the fixed identity
// rotation of frame a.
struct AbsoluteRotationPrior {
  explicit AbsoluteRotationPrior(double scale_in) : scale(scale_in) {}
  template <typename T>
  bool operator()(const T* rotation, T* residual) const {
    for (int k = 0; k < 3; ++k) residual[k] = T(scale) * rotation[k];
    return true;
  }
  double scale;
};

// A camera centre c = -R^T t (T_cam_world = (R, t)) against its pose
// prior's, in units of the prior's standard deviation.
struct PriorCentreResidual {
  PriorCentreResidual(const Eigen::Vector3d& prior_centre, double sigma)
      : centre(prior_centre), inverse_sigma(1.0 / sigma) {}
  template <typename T>
  bool operator()(const T* rotation, const T* translation, T* residual) const {
    const T inverse[3] = {-rotation[0], -rotation[1], -rotation[2]};
    const T minus_t[3] = {-translation[0], -translation[1], -translation[2]};
    T c[3];
    ceres::AngleAxisRotatePoint(inverse, minus_t, c);
    for (int k = 0; k < 3; ++k) residual[k] = T(inverse_sigma) * (c[k] - T(centre[k]));
    return true;
  }
  Eigen::Vector3d centre;
  double inverse_sigma;
};

// A camera orientation R (T_cam_world = (R, t)) against its pose prior's
// R_prior: the angle-axis of R R_prior^T in units of the prior's standard
// deviation (radians).
struct PriorOrientationResidual {
  PriorOrientationResidual(const Eigen::Matrix3d& R_prior_cam_world, double sigma_rad)
      : inverse_sigma(1.0 / sigma_rad) {
    const Eigen::Quaterniond q(R_prior_cam_world);
    prior_inverse[0] = q.w();
    prior_inverse[1] = -q.x();
    prior_inverse[2] = -q.y();
    prior_inverse[3] = -q.z();
  }
  template <typename T>
  bool operator()(const T* rotation, T* residual) const {
    T q[4], difference[4];
    ceres::AngleAxisToQuaternion(rotation, q);
    const T prior[4] = {T(prior_inverse[0]), T(prior_inverse[1]), T(prior_inverse[2]), T(prior_inverse[3])};
    ceres::QuaternionProduct(q, prior, difference);
    ceres::QuaternionToAngleAxis(difference, residual);
    for (int k = 0; k < 3; ++k) residual[k] *= T(inverse_sigma);
    return true;
  }
  double prior_inverse[4];  // w, x, y, z of R_prior^T
  double inverse_sigma;
};

// Inverse depth along ray0 that best explains x1 for the pose (R, t):
// least squares of x1 x (R ray0 + rho t) = 0.
double TriangulateInverseDepth(const Eigen::Matrix3d& R, const Eigen::Vector3d& t,
                               const Eigen::Vector3d& ray0, const Eigen::Vector3d& ray1) {
  const Eigen::Vector3d a = ray1.cross(R * ray0);
  const Eigen::Vector3d b = ray1.cross(t);
  const double bb = b.squaredNorm();
  return bb > 1e-18 ? -a.dot(b) / bb : 0.0;
}

struct TwoViewSolution {
  Eigen::Vector3d rotation = Eigen::Vector3d::Zero();  // angle-axis of R_cam1_cam0
  Eigen::Vector3d translation = Eigen::Vector3d::UnitX();
  std::vector<double> inverse_depth;
  double cost = std::numeric_limits<double>::infinity();
};

// Refines the two-view pair from a starting pose: pose b (|t| = 1) and one
// inverse depth per match, Cauchy reprojection loss (tracks on occlusion edges are
// gross outliers that a Huber loss lets pull the pose into the pan +
// forward-motion basin) plus the rotation prior.
TwoViewSolution RefineTwoView(const PinholeCamera& camera, const InitializerOptions& options, int threads,
                              double prior_px, const std::vector<Eigen::Vector3d>& rays0,
                              const std::vector<cv::Point2f>& points1, const Eigen::Matrix3d& R_start,
                              const Eigen::Vector3d& t_start) {
  TwoViewSolution solution;
  const Eigen::AngleAxisd angle_axis(R_start);
  solution.rotation = angle_axis.angle() * angle_axis.axis();
  solution.translation = t_start.normalized();
  const int n = static_cast<int>(rays0.size());
  solution.inverse_depth.resize(n);
  std::vector<double> positive;
  for (int k = 0; k < n; ++k) {
    const Eigen::Vector3d ray1 = camera.Ray(points1[k].x, points1[k].y);
    solution.inverse_depth[k] = TriangulateInverseDepth(R_start, solution.translation, rays0[k], ray1);
    if (solution.inverse_depth[k] > 0.0) positive.push_back(solution.inverse_depth[k]);
  }
  // Points that start behind camera 0 start at the median instead.
  const double fallback = positive.empty() ? 1e-2 : Median(positive);
  for (double& rho : solution.inverse_depth) {
    if (!(rho > 0.0)) rho = fallback;
  }
  ceres::Problem problem;
  for (int k = 0; k < n; ++k) {
    problem.AddResidualBlock(new ceres::AutoDiffCostFunction<TwoViewResidual, 2, 3, 3, 1>(
                                 new TwoViewResidual(rays0[k], points1[k], camera)),
                             new ceres::CauchyLoss(options.ba_loss_px), solution.rotation.data(),
                             solution.translation.data(), &solution.inverse_depth[k]);
  }
  problem.AddResidualBlock(new ceres::AutoDiffCostFunction<AbsoluteRotationPrior, 3, 3>(
                               new AbsoluteRotationPrior(camera.fx / prior_px)),
                           nullptr, solution.rotation.data());
  problem.SetManifold(solution.translation.data(), new ceres::SphereManifold<3>());
  solution.cost = SolveQuietly(options, threads, &problem).final_cost;
  // (t, rho) and (-t, -rho) fit equally: keep the points in front.
  int in_front = 0;
  for (double rho : solution.inverse_depth) in_front += rho > 0.0 ? 1 : -1;
  if (in_front < 0) {
    solution.translation = -solution.translation;
    for (double& rho : solution.inverse_depth) rho = -rho;
  }
  return solution;
}

// Direction of a pure translation (R = I) between two views: ray1 lies in
// the plane of ray0 and t, so t is orthogonal to every n = ray0 x ray1. Two
// matches fix it (t = n_i x n_j); RANSAC over such pairs, inliers within
// `threshold_px` of their epipolar line, then least squares over the
// inliers. The sign puts most points in front.
Eigen::Vector3d PureTranslationEpipole(const PinholeCamera& camera, const std::vector<cv::Point2f>& points0,
                                       const std::vector<cv::Point2f>& points1, double threshold_px) {
  const int n = static_cast<int>(points0.size());
  std::vector<Eigen::Vector3d> rays0(n), rays1(n), normals(n);
  for (int k = 0; k < n; ++k) {
    rays0[k] = camera.Ray(points0[k].x, points0[k].y);
    rays1[k] = camera.Ray(points1[k].x, points1[k].y);
    normals[k] = rays0[k].cross(rays1[k]);
  }
  const double focal = 0.5 * (camera.fx + camera.fy);
  // Distance (px) of x1 from the epipolar line t x ray0.
  auto residual = [&](const Eigen::Vector3d& t, int k) {
    const Eigen::Vector3d line = t.cross(rays0[k]);
    const double norm = line.head<2>().norm();
    return norm > 1e-15 ? focal * std::abs(line.dot(rays1[k])) / norm
                        : std::numeric_limits<double>::infinity();
  };
  cv::RNG rng(0x5eed);  // fixed: the same frames give the same start
  Eigen::Vector3d best_t = Eigen::Vector3d::UnitX();
  int best_count = -1;
  for (int iteration = 0; iteration < 300 && n >= 2; ++iteration) {
    const int i = rng.uniform(0, n);
    const int j = rng.uniform(0, n);
    if (i == j) continue;
    const Eigen::Vector3d t = normals[i].cross(normals[j]);
    if (!(t.norm() > 1e-15)) continue;
    int count = 0;
    for (int k = 0; k < n; ++k) count += residual(t.normalized(), k) <= threshold_px ? 1 : 0;
    if (count > best_count) {
      best_count = count;
      best_t = t.normalized();
    }
  }
  Eigen::Matrix3d normal_matrix = Eigen::Matrix3d::Zero();
  for (int k = 0; k < n; ++k) {
    if (residual(best_t, k) <= threshold_px) normal_matrix += normals[k] * normals[k].transpose();
  }
  Eigen::Vector3d t = best_t;
  if (best_count >= 2) {
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eigen(normal_matrix);
    t = eigen.eigenvectors().col(0);
  }
  int in_front = 0;
  for (int k = 0; k < n; ++k) {
    const double rho = TriangulateInverseDepth(Eigen::Matrix3d::Identity(), t, rays0[k], rays1[k]);
    in_front += rho > 0.0 ? 1 : -1;
  }
  return in_front < 0 ? Eigen::Vector3d(-t) : t;
}

// The tracks that see both frames a < b of the two-view pair: their points
// in both frames (0 = frame a, 1 = frame b) and their indices.
struct TwoViewMatches {
  int a = 0, b = 1;
  std::vector<cv::Point2f> points0, points1;
  std::vector<int> track_index;
  int Count() const { return static_cast<int>(points0.size()); }
  std::string Name() const { return "frames " + std::to_string(a) + "-" + std::to_string(b); }
};

TwoViewMatches CollectTwoViewMatches(const std::vector<Track>& tracks, int a, int b) {
  TwoViewMatches matches;
  matches.a = a;
  matches.b = b;
  for (size_t i = 0; i < tracks.size(); ++i) {
    const Track& track = tracks[i];
    if (track.Sees(a) && track.Sees(b)) {
      matches.points0.push_back(track.At(a));
      matches.points1.push_back(track.At(b));
      matches.track_index.push_back(static_cast<int>(i));
    }
  }
  return matches;
}

// The essential-matrix start of the pair: E by RANSAC, then recoverPose.
// Throws InitializationError when E is degenerate or has too few inliers.
struct EssentialStart {
  Eigen::Matrix3d R = Eigen::Matrix3d::Identity();  // R_cam1_cam0
  Eigen::Vector3d t = Eigen::Vector3d::UnitX();
  int ransac_inliers = 0;
  int pose_inliers = 0;  // RANSAC inliers that pass the cheirality check
};

EssentialStart EssentialMatrixStart(const PinholeCamera& camera, const InitializerOptions& options,
                                    const TwoViewMatches& matches) {
  const cv::Mat K = CameraMatrix(camera);
  cv::Mat inlier_mask;
  cv::Mat E = cv::findEssentialMat(matches.points0, matches.points1, K, cv::RANSAC, options.ransac_confidence,
                                   options.ransac_threshold_px, inlier_mask);
  if (E.rows > 3 && E.cols == 3) E = E.rowRange(0, 3).clone();  // ambiguous minimal sets
  if (E.rows != 3 || E.cols != 3) {
    throw InitializationError("initialisation: " + matches.Name() + " give no essential matrix (" +
                              std::to_string(matches.Count()) + " matches; degenerate geometry)");
  }
  EssentialStart start;
  start.ransac_inliers = cv::countNonZero(inlier_mask);
  if (start.ransac_inliers < options.min_inliers) {
    throw InitializationError(
        "initialisation: " + matches.Name() + ": only " + std::to_string(start.ransac_inliers) + " of " +
        std::to_string(matches.Count()) + " matches consistent with one relative pose (need " +
        std::to_string(options.min_inliers) + ")");
  }
  // The default far-point cut (50 baselines) would drop most points: the
  // baseline of two consecutive frames is ~1 % of the scene depth.
  cv::Mat R_cv, t_cv, triangulated_points;
  cv::Mat pose_mask = inlier_mask.clone();
  start.pose_inliers = cv::recoverPose(E, matches.points0, matches.points1, K, R_cv, t_cv,
                                       /*distanceThresh=*/1e6, pose_mask, triangulated_points);
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) start.R(r, c) = R_cv.at<double>(r, c);
    start.t[r] = t_cv.at<double>(r);
  }
  return start;
}

// Median parallax of the pair's matches that the rotation of T_cam1_cam0
// leaves. A static camera or a pure rotation leaves none: the scale and the
// depths would be undefined, so too little throws.
double CheckTwoViewParallax(const PinholeCamera& camera, const InitializerOptions& options,
                            const TwoViewMatches& matches, const SE3& T_cam1_cam0) {
  std::vector<double> parallaxes;
  for (int k = 0; k < matches.Count(); ++k) {
    parallaxes.push_back(TranslationalParallax(camera, T_cam1_cam0, matches.points0[k], matches.points1[k]));
  }
  const double parallax = Median(parallaxes);
  if (parallax < options.min_parallax_px) {
    throw InitializationError("initialisation: " + matches.Name() +
                              Format(" have too little parallax (median %.2f px not explained by "
                                     "rotation, need %.2f px); the camera must translate between them",
                                     parallax, options.min_parallax_px));
  }
  return parallax;
}

// The points of the chosen two-view solution that lie in front of camera a
// and reproject into frame b: added to the structure, linked to their tracks.
// Returns how many.
int AddTwoViewPoints(const PinholeCamera& camera, const InitializerOptions& options,
                     const TwoViewMatches& matches, const std::vector<Eigen::Vector3d>& rays0,
                     const TwoViewSolution& solution, std::vector<Track>* tracks,
                     SparseStructure* structure) {
  int triangulated = 0;
  for (int k = 0; k < matches.Count(); ++k) {
    const double rho = solution.inverse_depth[k];
    if (!(rho > 1e-9)) continue;
    const Eigen::Vector3d point = rays0[k] / rho;
    Track& track = (*tracks)[matches.track_index[k]];
    if (ReprojectionError(camera, structure->T_cam_world[matches.b], point, track.At(matches.b)) >
        2.0 * options.ransac_threshold_px) {
      continue;
    }
    track.point_id = static_cast<int>(structure->points_world.size());
    structure->points_world.push_back(point);
    structure->point_inlier.push_back(1);
    ++triangulated;
  }
  return triangulated;
}

// A candidate pair for the two-view start: frames a < b, the tracks they
// share and the median displacement no rotation explains (RotationFreeParallax).
struct InitialPair {
  int a = 0, b = 1;
  int matches = 0;
  double rotation_free_parallax = 0.0;
};

// The pair's two-view geometry: the paper's SfM step. Essential matrix
// (RANSAC) + recoverPose give one start; because a narrow field of view leaves
// the rotation / translation split nearly unobservable (see RotationPrior), a
// second start assumes no rotation and takes the epipole from the linear
// pure-translation constraint (x0 x x1) . t = 0. Both are refined
// (RefineTwoView, the rotation prior scaled by the frame gap) and the lower
// final cost wins. Sets T_cam_world of a (identity: world = camera a) and b
// (|c_b - c_a| = 1) and the points. Throws InitializationError with the reason
// when the pair does not allow it.
void TwoViewInitialisation(const PinholeCamera& camera, const InitializerOptions& options, int threads,
                           const InitialPair& pair, std::vector<Track>* tracks, SparseStructure* structure) {
  const TwoViewMatches matches = CollectTwoViewMatches(*tracks, pair.a, pair.b);
  const std::vector<cv::Point2f>& points0 = matches.points0;
  const std::vector<cv::Point2f>& points1 = matches.points1;
  const int count = matches.Count();
  const EssentialStart essential = EssentialMatrixStart(camera, options, matches);

  // Both starts are refined on all matches (Cauchy loss), so that their final
  // costs compare; points that stay off are not triangulated below. The prior
  // is per frame step: a pair k frames apart may turn k times as much.
  const double prior_px = options.rotation_prior_px * (pair.b - pair.a);
  std::vector<Eigen::Vector3d> rays0(count);
  for (int k = 0; k < count; ++k) rays0[k] = camera.Ray(points0[k].x, points0[k].y);
  const Eigen::Vector3d t_translation =
      PureTranslationEpipole(camera, points0, points1, options.ransac_threshold_px);
  const TwoViewSolution from_essential =
      RefineTwoView(camera, options, threads, prior_px, rays0, points1, essential.R, essential.t);
  const TwoViewSolution from_translation = RefineTwoView(camera, options, threads, prior_px, rays0, points1,
                                                         Eigen::Matrix3d::Identity(), t_translation);
  const bool essential_wins = from_essential.cost <= from_translation.cost;
  const TwoViewSolution& best = essential_wins ? from_essential : from_translation;

  // T_camb_cama with |t| = 1: world = camera a, centres 1 apart.
  structure->reference = pair.a;
  structure->baseline_frame = pair.b;
  structure->T_cam_world[pair.a] = SE3();
  structure->T_cam_world[pair.b] = SE3(RotationFromAngleAxis(best.rotation), best.translation.normalized());
  const double parallax = CheckTwoViewParallax(camera, options, matches, structure->T_cam_world[pair.b]);
  const int triangulated = AddTwoViewPoints(camera, options, matches, rays0, best, tracks, structure);
  if (triangulated < options.min_inliers) {
    throw InitializationError("initialisation: only " + std::to_string(triangulated) + " points of " +
                              matches.Name() +
                              " triangulate in front of both cameras "
                              "(degenerate geometry)");
  }
  const std::string name = Format("two-view %.0f-%.0f: ", pair.a, pair.b);
  structure->log.push_back(name +
                           Format("%.0f matches, %.0f RANSAC inliers, %.0f pass cheirality, parallax %.2f px "
                                  "(%.2f px not explained by any rotation), %.0f points",
                                  count, essential.ransac_inliers, essential.pose_inliers, parallax,
                                  pair.rotation_free_parallax, triangulated));
  structure->log.push_back(name +
                           Format("refined cost from E %.4g (rotation %.3f deg), from pure translation "
                                  "%.4g (rotation %.3f deg)",
                                  from_essential.cost, from_essential.rotation.norm() * 180.0 / M_PI,
                                  from_translation.cost, from_translation.rotation.norm() * 180.0 / M_PI));
}

// Camera pose of `frame` from its 2D-3D correspondences (PnP, RANSAC), started
// from `predicted` (T_cam_world).
void LocaliseFrame(const PinholeCamera& camera, const InitializerOptions& options, int frame,
                   const SE3& predicted, const std::vector<Track>& tracks, SparseStructure* structure) {
  std::vector<cv::Point3f> object;
  std::vector<cv::Point2f> image;
  for (const Track& track : tracks) {
    if (track.point_id < 0 || !track.Sees(frame) || !structure->point_inlier[track.point_id]) {
      continue;
    }
    const Eigen::Vector3d& p = structure->points_world[track.point_id];
    object.emplace_back(static_cast<float>(p.x()), static_cast<float>(p.y()), static_cast<float>(p.z()));
    image.push_back(track.At(frame));
  }
  if (static_cast<int>(object.size()) < options.min_pnp_inliers) {
    throw InitializationError("initialisation: frame " + std::to_string(frame) + " sees only " +
                              std::to_string(object.size()) + " triangulated points (need " +
                              std::to_string(options.min_pnp_inliers) + ")");
  }
  cv::Mat rvec, tvec;
  ToOpenCv(predicted, &rvec, &tvec);
  std::vector<int> inliers;
  const bool ok =
      cv::solvePnPRansac(object, image, CameraMatrix(camera), cv::noArray(), rvec, tvec,
                         /*useExtrinsicGuess=*/true, 200, static_cast<float>(options.pnp_threshold_px),
                         options.ransac_confidence, inliers, cv::SOLVEPNP_ITERATIVE);
  if (!ok || static_cast<int>(inliers.size()) < options.min_pnp_inliers) {
    throw InitializationError("initialisation: frame " + std::to_string(frame) + ": PnP found " +
                              std::to_string(inliers.size()) + " of " + std::to_string(object.size()) +
                              " inliers (need " + std::to_string(options.min_pnp_inliers) + ")");
  }
  std::vector<cv::Point3f> object_inliers;
  std::vector<cv::Point2f> image_inliers;
  for (int index : inliers) {
    object_inliers.push_back(object[index]);
    image_inliers.push_back(image[index]);
  }
  cv::solvePnPRefineLM(object_inliers, image_inliers, CameraMatrix(camera), cv::noArray(), rvec, tvec);
  structure->T_cam_world[frame] = FromOpenCv(rvec, tvec);
  structure->log.push_back(
      Format("pnp frame %.0f: %.0f of %.0f inliers", frame, inliers.size(), object.size()));
}

// Adds the reprojection residuals of every observation of an inlier point to
// `problem`; from round 1 on, observations beyond `outlier_px` stay out.
// Returns how many were added.
int AddReprojectionResiduals(const PinholeCamera& camera, const InitializerOptions& options,
                             const std::vector<Track>& tracks, const SparseStructure& structure, int round,
                             std::vector<PoseParameters>* poses, std::vector<std::array<double, 3>>* points,
                             ceres::Problem* problem) {
  const double outlier_px = options.pnp_threshold_px;
  int observations = 0;
  for (const Track& track : tracks) {
    if (track.point_id < 0 || !structure.point_inlier[track.point_id]) continue;
    double* point = (*points)[track.point_id].data();
    for (int f = track.first_frame; f <= track.LastFrame(); ++f) {
      if (round > 0 && ReprojectionError(camera, FromParameters((*poses)[f]), Eigen::Vector3d(point),
                                         track.At(f)) > outlier_px) {
        continue;
      }
      problem->AddResidualBlock(new ceres::AutoDiffCostFunction<ReprojectionResidual, 2, 3, 3, 3>(
                                    new ReprojectionResidual(track.At(f), camera)),
                                new ceres::CauchyLoss(options.ba_loss_px), (*poses)[f].rotation,
                                (*poses)[f].translation, point);
      ++observations;
    }
  }
  return observations;
}

// The PriorCentreResiduals of structure.prior_centres and, with
// prior_rotation_sigma, the PriorOrientationResiduals of the same frames
// (Huber loss, quadratic up to kPriorHuberSigmas), on the poses that the
// problem already has. Returns whether there was any.
constexpr double kPriorHuberSigmas = 2.0;

bool AddPosePriorResiduals(const SparseStructure& structure, std::vector<PoseParameters>* poses,
                             ceres::Problem* problem) {
  bool any = false;
  for (size_t t = 0; t < structure.prior_centres.size(); ++t) {
    PoseParameters& pose = (*poses)[t];
    if (!structure.prior_centres[t] || !problem->HasParameterBlock(pose.rotation)) continue;
    problem->AddResidualBlock(new ceres::AutoDiffCostFunction<PriorCentreResidual, 3, 3, 3>(
                                  new PriorCentreResidual(*structure.prior_centres[t], structure.prior_sigma)),
                              new ceres::HuberLoss(kPriorHuberSigmas), pose.rotation, pose.translation);
    if (structure.prior_rotation_sigma > 0.0) {
      problem->AddResidualBlock(
          new ceres::AutoDiffCostFunction<PriorOrientationResidual, 3, 3>(new PriorOrientationResidual(
              structure.prior_orientations[t], structure.prior_rotation_sigma)),
          new ceres::HuberLoss(kPriorHuberSigmas), pose.rotation);
    }
    any = true;
  }
  return any;
}

// RMS reprojection error (px) of the observations of inlier points within
// `outlier_px`.
double InlierRms(const PinholeCamera& camera, const std::vector<Track>& tracks,
                 const SparseStructure& structure, const std::vector<PoseParameters>& poses,
                 const std::vector<std::array<double, 3>>& points, double outlier_px) {
  double squares = 0.0;
  int inliers = 0;
  for (const Track& track : tracks) {
    if (track.point_id < 0 || !structure.point_inlier[track.point_id]) continue;
    for (int f = track.first_frame; f <= track.LastFrame(); ++f) {
      const double error = ReprojectionError(camera, FromParameters(poses[f]),
                                             Eigen::Vector3d(points[track.point_id].data()), track.At(f));
      if (error <= outlier_px) {
        squares += error * error;
        ++inliers;
      }
    }
  }
  return std::sqrt(squares / std::max(1, inliers));
}

// All poses and points by reprojection error (Cauchy loss) plus the
// frame-to-frame RotationPrior (kappa: structure->turn_rate, fitted when
// structure->fit_turn_rate), in the two-view pair's gauge: camera a fixed
// (T_cam_world = identity) and |t_b| = |c_b - c_a| = 1 on a sphere (the
// output gauge is set later, see NormaliseGauge). With a pose prior
// (AdjustToPosePrior) its residuals fix the gauge instead: camera a is free
// but for its orientation, which is held unless the prior's orientations
// are used, and no sphere. Two rounds, dropping observations
// beyond the outlier threshold in between. Returns the RMS reprojection error
// (px) of the observations within the threshold.
double BundleAdjust(const PinholeCamera& camera, const InitializerOptions& options, int threads,
                    const std::vector<Track>& tracks, SparseStructure* structure, int* num_observations) {
  const int num_frames = static_cast<int>(structure->T_cam_world.size());
  std::vector<PoseParameters> poses(num_frames);
  for (int t = 0; t < num_frames; ++t) poses[t] = ToParameters(structure->T_cam_world[t]);
  std::vector<std::array<double, 3>> points(structure->points_world.size());
  for (size_t i = 0; i < points.size(); ++i) {
    for (int k = 0; k < 3; ++k) points[i][k] = structure->points_world[i][k];
  }
  const double outlier_px = options.pnp_threshold_px;
  double rms = 0.0;
  for (int round = 0; round < 2; ++round) {
    ceres::Problem problem;
    const int observations =
        AddReprojectionResiduals(camera, options, tracks, *structure, round, &poses, &points, &problem);
    if (problem.NumResidualBlocks() == 0) break;
    for (int t = 1; t < num_frames; ++t) {
      problem.AddResidualBlock(new ceres::AutoDiffCostFunction<RotationPrior, 3, 3, 3, 3, 3, 1>(
                                   new RotationPrior(camera.fx, options.rotation_prior_px)),
                               nullptr, poses[t - 1].rotation, poses[t - 1].translation, poses[t].rotation,
                               poses[t].translation, &structure->turn_rate);
    }
    if (num_frames > 1 && !structure->fit_turn_rate) problem.SetParameterBlockConstant(&structure->turn_rate);
    const bool prior = AddPosePriorResiduals(*structure, &poses, &problem);
    // The gauge: with a prior its centres fix the translation and scale (and
    // its orientations, when used, the rotation) of the world.
    PoseParameters& reference = poses[structure->reference];
    if (problem.HasParameterBlock(reference.rotation)) {
      if (!prior || structure->prior_rotation_sigma == 0.0) {
        problem.SetParameterBlockConstant(reference.rotation);
      }
      if (!prior) problem.SetParameterBlockConstant(reference.translation);
    }
    if (!prior && problem.HasParameterBlock(poses[structure->baseline_frame].translation)) {
      problem.SetManifold(poses[structure->baseline_frame].translation, new ceres::SphereManifold<3>());
    }
    SolveQuietly(options, threads, &problem);
    rms = InlierRms(camera, tracks, *structure, poses, points, outlier_px);
    *num_observations = observations;
  }
  for (int t = 0; t < num_frames; ++t) structure->T_cam_world[t] = FromParameters(poses[t]);
  // Points whose observations mostly disagree leave the depth-range statistics.
  for (const Track& track : tracks) {
    if (track.point_id < 0) continue;
    Eigen::Vector3d point(points[track.point_id].data());
    structure->points_world[track.point_id] = point;
    int bad = 0;
    for (int f = track.first_frame; f <= track.LastFrame(); ++f) {
      if (ReprojectionError(camera, structure->T_cam_world[f], point, track.At(f)) > outlier_px) {
        ++bad;
      }
    }
    if (2 * bad > static_cast<int>(track.points.size())) structure->point_inlier[track.point_id] = 0;
  }
  return rms;
}

// Reprojection errors of the inlier points' observations under the
// structure's poses and points: the sum of squares, each capped at
// `outlier_px`^2 (a track that neither of two solutions fits counts the same
// in both), and the sum of squares and count of those within `outlier_px`.
// `inlier` selects the points (a solution's point_inlier).
struct ReprojectionCost {
  double capped_squares = 0.0;
  double inlier_squares = 0.0;
  int inlier_observations = 0;
};

ReprojectionCost MeasureReprojectionCost(const PinholeCamera& camera, const std::vector<Track>& tracks,
                                         const SparseStructure& structure, const std::vector<char>& inlier,
                                         double outlier_px) {
  ReprojectionCost cost;
  for (const Track& track : tracks) {
    if (track.point_id < 0 || !inlier[track.point_id]) continue;
    const Eigen::Vector3d& point = structure.points_world[track.point_id];
    for (int f = track.first_frame; f <= track.LastFrame(); ++f) {
      const double error = ReprojectionError(camera, structure.T_cam_world[f], point, track.At(f));
      if (error <= outlier_px) {
        cost.inlier_squares += error * error;
        ++cost.inlier_observations;
      }
      cost.capped_squares += std::min(error, outlier_px) * std::min(error, outlier_px);
    }
  }
  return cost;
}

// Upper `z`-sigma quantile of the chi-square distribution with k degrees of
// freedom (Wilson-Hilferty: (chi2 / k)^(1/3) is nearly normal).
double ChiSquareQuantile(int k, double z) {
  const double v = 2.0 / (9.0 * k);
  const double cube_root = 1.0 - v + z * std::sqrt(v);
  return k * cube_root * cube_root * cube_root;
}

// Median depth (pair baselines) of the inlier points in the reference camera.
double MedianPointDepth(const SparseStructure& structure) {
  std::vector<double> depths;
  for (size_t i = 0; i < structure.points_world.size(); ++i) {
    if (!structure.point_inlier[i]) continue;
    const double z = (structure.T_cam_world[structure.reference] * structure.points_world[i]).z();
    if (z > 0.0) depths.push_back(z);
  }
  return depths.empty() ? 0.0 : Median(depths);
}

// Leaves out the tracks that the adjusted poses and their own point do not
// explain to the tracking noise (track_consistency_z). A Lucas-Kanade track
// that slides along an occlusion boundary (a leaf's edge, a T-junction)
// follows no single point, yet each of its observations can stay within the
// outlier threshold, where the Cauchy loss (ba_loss_px) weighs it almost
// fully; a few such tracks pull the poses (BENCHMARKS.md "Tracks that follow
// no point"). A track's squared reprojection errors within pnp_threshold_px,
// over n of them, are sigma^2 chi-square with 2n - 3 degrees of freedom
// (its point takes 3) where it follows a point; sigma^2 is their sum over
// all tracks divided by the sum of the degrees of freedom, leaving out
// tracks beyond 9x the median of those ratios. A track beyond the
// chi-square quantile at track_consistency_z has its point marked an
// outlier. Returns how many were; *sigma_px is sigma.
int DropInconsistentTracks(const PinholeCamera& camera, const InitializerOptions& options,
                           const std::vector<Track>& tracks, SparseStructure* structure, double* sigma_px) {
  struct TrackError {
    int point_id = -1;
    double squares = 0.0;
    int degrees_of_freedom = -3;
  };
  std::vector<TrackError> errors;
  for (const Track& track : tracks) {
    if (track.point_id < 0 || !structure->point_inlier[track.point_id]) continue;
    TrackError error;
    error.point_id = track.point_id;
    for (int f = track.first_frame; f <= track.LastFrame(); ++f) {
      const double e = ReprojectionError(camera, structure->T_cam_world[f],
                                         structure->points_world[track.point_id], track.At(f));
      if (e > options.pnp_threshold_px) continue;
      error.squares += e * e;
      error.degrees_of_freedom += 2;
    }
    if (error.degrees_of_freedom > 0) errors.push_back(error);
  }
  *sigma_px = 0.0;
  if (errors.empty()) return 0;
  std::vector<double> ratios;
  for (const TrackError& error : errors) ratios.push_back(error.squares / error.degrees_of_freedom);
  const double cap = 9.0 * Median(ratios);
  double squares = 0.0;
  int degrees_of_freedom = 0;
  for (const TrackError& error : errors) {
    if (error.squares > cap * error.degrees_of_freedom) continue;
    squares += error.squares;
    degrees_of_freedom += error.degrees_of_freedom;
  }
  if (degrees_of_freedom == 0 || !(squares > 0.0)) return 0;
  const double sigma_squared = squares / degrees_of_freedom;
  *sigma_px = std::sqrt(sigma_squared);
  int dropped = 0;
  for (const TrackError& error : errors) {
    if (error.squares >
        sigma_squared * ChiSquareQuantile(error.degrees_of_freedom, options.track_consistency_z)) {
      structure->point_inlier[error.point_id] = 0;
      ++dropped;
    }
  }
  return dropped;
}

// DropInconsistentTracks after an adjustment whose RMS error is `rms`, with
// its line in the summary, and the adjustment again where it dropped any
// (track_consistency_z > 0). Returns the RMS error of the structure kept.
double LeaveOutInconsistentTracks(const PinholeCamera& camera, const InitializerOptions& options, int threads,
                                  const std::vector<Track>& tracks, double rms, SparseStructure* structure,
                                  int* num_observations, std::ostringstream* summary) {
  if (!(options.track_consistency_z > 0.0)) return rms;
  double sigma_px = 0.0;
  const int dropped = DropInconsistentTracks(camera, options, tracks, structure, &sigma_px);
  *summary << Format("track consistency: %.0f tracks follow no point (sigma %.3f px, rms %.3f px before)\n",
                     dropped, sigma_px, rms);
  return dropped > 0 ? BundleAdjust(camera, options, threads, tracks, structure, num_observations) : rms;
}

// Decides the turn rate kappa of the RotationPrior (model selection between
// a camera that expects no turn and one that keeps a point in view): the
// structure, adjusted with kappa = 0, is adjusted again from there with kappa
// free. Where kappa = 0 is right, freeing it gains only what fitting the
// tracking noise with one more parameter gains: a chi-square(1) amount in
// units of the noise variance sigma^2 (estimated from the free solution's
// residuals); a camera that turns (the arc path: kappa = 0 takes the turn for
// sideways motion and bends the inverse depths, RotationPrior) gains far
// more. The free solution is kept when the gain in reprojection cost exceeds
// the chi-square quantile of `test_z` (fixation_test_z where the flow turn
// check follows, fixation_test_alone_z where it does not). Returns the RMS
// reprojection error of the solution kept.
double SelectFixationTurn(const PinholeCamera& camera, const InitializerOptions& options, double test_z,
                          int threads, const std::vector<Track>& tracks, double rms,
                          SparseStructure* structure, int* num_observations, std::ostringstream* summary,
                          std::optional<SparseStructure>* rejected_turn,
                          std::optional<SparseStructure>* kept_turn_still) {
  if (!options.fixation_prior || structure->T_cam_world.size() < 3) return rms;
  SparseStructure turning = *structure;
  turning.fit_turn_rate = true;
  int turning_observations = 0;
  const double turning_rms = BundleAdjust(camera, options, threads, tracks, &turning, &turning_observations);
  // Both solutions on the points the free one keeps (a subset: the
  // adjustment only ever drops points).
  const double outlier_px = options.pnp_threshold_px;
  const ReprojectionCost still =
      MeasureReprojectionCost(camera, tracks, *structure, turning.point_inlier, outlier_px);
  const ReprojectionCost turned =
      MeasureReprojectionCost(camera, tracks, turning, turning.point_inlier, outlier_px);
  int points = 0;
  for (char inlier : turning.point_inlier) points += inlier ? 1 : 0;
  const int num_frames = static_cast<int>(structure->T_cam_world.size());
  const int residuals = 2 * turned.inlier_observations;
  const int parameters = 3 * points + 6 * num_frames - 6;  // 7 gauge freedoms, kappa
  const double sigma2 = turned.inlier_squares / std::max(1, residuals - parameters);
  const double gain = (still.capped_squares - turned.capped_squares) / std::max(sigma2, 1e-12);
  const double bound = ChiSquareQuantile(1, test_z);
  const bool turns = gain > bound && turning.turn_rate != 0.0;
  const double median_depth = MedianPointDepth(turning);
  *summary << Format(
                  "rotation prior: a turn towards a point at %.3g median depths lowers the reprojection cost "
                  "by %.1f sigma^2 (sigma %.3f px; chi-square(1) bound %.1f): ",
                  1.0 / (turning.turn_rate * median_depth), gain, std::sqrt(sigma2), bound)
           << (turns ? "kept\n" : "no turn\n");
  if (!turns) {
    if (turning.turn_rate != 0.0) *rejected_turn = std::move(turning);
    return rms;
  }
  *kept_turn_still = std::move(*structure);
  *structure = std::move(turning);
  *num_observations = turning_observations;
  return turning_rms;
}

// ---------------------------------------------------------------- depths

// One neighbour s of a frame t in eq:initializationScene: the two images that
// carry the same blur (B_t through s's blur, B_s through t's blur) and where
// a point of t's grid appears in each.
struct NeighbourImages {
  int frame = 0;
  cv::Mat reference;  // Psi_s o B_t on t's grid (or B_t when not blur-aware)
  cv::Mat source;     // Psi_t o B_s on s's grid (or B_s)
  // From t's shutter-close camera to where the reference / source show a
  // point: their blur centroids (BuildBlurredPairs). One transfer, or with a
  // rolling shutter one per row of t (that row's read-out delay).
  std::vector<PixelTransferF> to_reference, to_source;
};

// Per-thread buffers of the sweep and the TV-L1 solver, reused across frames.
struct DepthWorkspace {
  std::vector<float> cost;         // pixel-major: cost[pixel * planes + plane]
  std::vector<float> plane_depth;  // depth of one hypothesis per pixel
  std::vector<float> difference;   // per neighbour, one plane
  std::vector<float> row;          // warped coordinates of one row
  std::vector<float> valid;
  std::vector<float> box_row, aggregated, aggregated_valid;
  std::vector<float> sum, weight;
  std::vector<float> a, u, u_bar, px, py, tv_weight;
  std::vector<float> cost_min, cost_max;
};

// Sum over a (2r+1)^2 window, separable, zero outside the image.
void BoxSum(const float* in, int width, int height, int radius, std::vector<float>* row_buffer, float* out) {
  row_buffer->resize(static_cast<size_t>(width) * height);
  float* rows = row_buffer->data();
  for (int y = 0; y < height; ++y) {
    const float* line = in + static_cast<size_t>(y) * width;
    float* dst = rows + static_cast<size_t>(y) * width;
    float running = 0.0f;
    for (int x = 0; x <= std::min(radius, width - 1); ++x) running += line[x];
    for (int x = 0; x < width; ++x) {
      dst[x] = running;
      const int add = x + radius + 1;
      const int remove = x - radius;
      if (add < width) running += line[add];
      if (remove >= 0) running -= line[remove];
    }
  }
  for (int x = 0; x < width; ++x) {
    float running = 0.0f;
    for (int y = 0; y <= std::min(radius, height - 1); ++y) running += rows[y * width + x];
    for (int y = 0; y < height; ++y) {
      out[static_cast<size_t>(y) * width + x] = running;
      const int add = y + radius + 1;
      const int remove = y - radius;
      if (add < height) running += rows[add * width + x];
      if (remove >= 0) running -= rows[remove * width + x];
    }
  }
}

// Inverse-depth hypotheses of one sweep: plane i of pixel x has the
// normalised inverse depth u = base[x] + (i - centre) * step, and
// rho = rho_min + u * (rho_max - rho_min). Pass 0 has base = 0, centre = 0
// (fronto-parallel planes over the whole range); later passes a narrow band
// around the previous estimate.
struct PlaneSet {
  int planes = 0;
  float centre = 0.0f;
  float step = 0.0f;
  const std::vector<float>* base = nullptr;
  double rho_min = 0.0;
  double rho_max = 1.0;
  float U(int pixel, int plane) const { return (*base)[pixel] + (static_cast<float>(plane) - centre) * step; }
  double Rho(float u) const { return rho_min + u * (rho_max - rho_min); }
};

// Per pixel of t (depth `depth`, 0 = none): the colour-averaged |difference|
// of reference and source at the point's blur centroids, and whether the
// source sees it. The reference is read clamped: its offset from the pixel is
// a fraction of the blur, and the capture operator replicates the border too.
template <int kChannels>
void PlaneDifferences(const NeighbourImages& neighbour, const float* depth, int width, int height,
                      std::vector<float>* scratch, float* difference_out, float* valid_out) {
  const float max_x = static_cast<float>(width - 1);
  const float max_y = static_cast<float>(height - 1);
  constexpr float kInvChannels = 1.0f / kChannels;
  const float* reference = neighbour.reference.ptr<float>();
  const float* source = neighbour.source.ptr<float>();
  const int stride = width * kChannels;
  // Coordinates of a row first (a branch-free loop the compiler vectorises),
  // then the bilinear reads.
  scratch->resize(static_cast<size_t>(4) * width);
  float* ru = scratch->data();
  float* rv = ru + width;
  float* su = rv + width;
  float* sv = su + width;
  const bool per_row = neighbour.to_reference.size() > 1;
  for (int y = 0; y < height; ++y) {
    const PixelTransferF& to_reference = neighbour.to_reference[per_row ? y : 0];
    const PixelTransferF& to_source = neighbour.to_source[per_row ? y : 0];
    float base_ref[3], base_src[3];
    to_reference.RowBase(static_cast<float>(y), base_ref);
    to_source.RowBase(static_cast<float>(y), base_src);
    const float* row_depth = depth + static_cast<size_t>(y) * width;
    float* difference_row = difference_out + static_cast<size_t>(y) * width;
    float* valid_row = valid_out + static_cast<size_t>(y) * width;
#pragma omp simd
    for (int x = 0; x < width; ++x) {
      const float d = row_depth[x];
      const float xf = static_cast<float>(x);
      const float zs = d * (to_source.h[6] * xf + base_src[2]) + to_source.t[2];
      const float zr = d * (to_reference.h[6] * xf + base_ref[2]) + to_reference.t[2];
      const float inv_zs = 1.0f / zs;
      const float inv_zr = 1.0f / zr;
      const float us = (d * (to_source.h[0] * xf + base_src[0]) + to_source.t[0]) * inv_zs;
      const float vs = (d * (to_source.h[3] * xf + base_src[1]) + to_source.t[1]) * inv_zs;
      const float ur = (d * (to_reference.h[0] * xf + base_ref[0]) + to_reference.t[0]) * inv_zr;
      const float vr = (d * (to_reference.h[3] * xf + base_ref[1]) + to_reference.t[1]) * inv_zr;
      const bool ok = (d > 0.0f) & (zs > 1e-9f) & (zr > 1e-9f) & (us >= 0.0f) & (vs >= 0.0f) & (us <= max_x) &
                      (vs <= max_y);
      valid_row[x] = ok ? 1.0f : 0.0f;
      su[x] = ok ? us : 0.0f;
      sv[x] = ok ? vs : 0.0f;
      ru[x] = ok ? std::min(std::max(ur, 0.0f), max_x) : 0.0f;
      rv[x] = ok ? std::min(std::max(vr, 0.0f), max_y) : 0.0f;
    }
    for (int x = 0; x < width; ++x) {
      const int rx0 = std::min(static_cast<int>(ru[x]), width - 2);
      const int ry0 = std::min(static_cast<int>(rv[x]), height - 2);
      const int sx0 = std::min(static_cast<int>(su[x]), width - 2);
      const int sy0 = std::min(static_cast<int>(sv[x]), height - 2);
      const float rfx = ru[x] - rx0, rfy = rv[x] - ry0;
      const float sfx = su[x] - sx0, sfy = sv[x] - sy0;
      const float* r0 = reference + static_cast<size_t>(ry0) * stride + rx0 * kChannels;
      const float* s0 = source + static_cast<size_t>(sy0) * stride + sx0 * kChannels;
      float difference = 0.0f;
      for (int c = 0; c < kChannels; ++c) {
        const float r_top = r0[c] + rfx * (r0[c + kChannels] - r0[c]);
        const float r_bottom = r0[c + stride] + rfx * (r0[c + stride + kChannels] - r0[c + stride]);
        const float s_top = s0[c] + sfx * (s0[c + kChannels] - s0[c]);
        const float s_bottom = s0[c + stride] + sfx * (s0[c + stride + kChannels] - s0[c + stride]);
        difference += std::abs((s_top + sfy * (s_bottom - s_top)) - (r_top + rfy * (r_bottom - r_top)));
      }
      difference_row[x] = difference * kInvChannels * valid_row[x];
    }
  }
}

// The data term of eq:initializationScene for every pixel and hypothesis:
// per neighbour the L1 difference of the equally blurred images averaged over
// colour and over a (2r+1)^2 patch (robust to the residual blur mismatch and
// noise), truncated at `truncation` (occlusions), then averaged over the
// neighbours that see the pixel. No neighbour: `truncation`.
void ComputeCostVolume(const std::vector<NeighbourImages>& neighbours, const PlaneSet& planes,
                       const InitializerOptions& options, int width, int height, DepthWorkspace* ws) {
  const int pixels = width * height;
  const int num_neighbours = static_cast<int>(neighbours.size());
  const int radius = options.patch_radius_px;
  const float truncation = static_cast<float>(options.cost_truncation);
  const float min_valid = 0.5f * (2 * radius + 1) * (2 * radius + 1);
  ws->cost.assign(static_cast<size_t>(pixels) * planes.planes, truncation);
  ws->difference.resize(pixels);
  ws->valid.resize(pixels);
  ws->aggregated.resize(pixels);
  ws->aggregated_valid.resize(pixels);
  ws->sum.resize(pixels);
  ws->weight.resize(pixels);
  ws->plane_depth.resize(pixels);
  for (int plane = 0; plane < planes.planes; ++plane) {
    // Depth of every pixel's hypothesis, shared by the neighbours.
    for (int pixel = 0; pixel < pixels; ++pixel) {
      const double rho = planes.Rho(planes.U(pixel, plane));
      ws->plane_depth[pixel] = rho > 1e-12 ? static_cast<float>(1.0 / rho) : 0.0f;
    }
    std::fill(ws->sum.begin(), ws->sum.end(), 0.0f);
    std::fill(ws->weight.begin(), ws->weight.end(), 0.0f);
    for (int n = 0; n < num_neighbours; ++n) {
      if (neighbours[n].reference.channels() == 3) {
        PlaneDifferences<3>(neighbours[n], ws->plane_depth.data(), width, height, &ws->row,
                            ws->difference.data(), ws->valid.data());
      } else {
        PlaneDifferences<1>(neighbours[n], ws->plane_depth.data(), width, height, &ws->row,
                            ws->difference.data(), ws->valid.data());
      }
      BoxSum(ws->difference.data(), width, height, radius, &ws->box_row, ws->aggregated.data());
      BoxSum(ws->valid.data(), width, height, radius, &ws->box_row, ws->aggregated_valid.data());
      for (int pixel = 0; pixel < pixels; ++pixel) {
        const float count = ws->aggregated_valid[pixel];
        if (count < min_valid || ws->valid[pixel] == 0.0f) continue;
        ws->sum[pixel] += std::min(ws->aggregated[pixel] / count, truncation);
        ws->weight[pixel] += 1.0f;
      }
    }
    for (int pixel = 0; pixel < pixels; ++pixel) {
      if (ws->weight[pixel] > 0.0f) {
        ws->cost[static_cast<size_t>(pixel) * planes.planes + plane] = ws->sum[pixel] / ws->weight[pixel];
      }
    }
  }
}

// Per pixel of the cost volume in ws->cost: the cost range (it bounds the
// search for a below) and the best plane, which starts a; u starts at u_init
// (or at a), the dual p at 0.
void InitialiseTvL1(const PlaneSet& planes, int pixels, const std::vector<float>* u_init,
                    DepthWorkspace* ws) {
  const int L = planes.planes;
  const float* cost = ws->cost.data();
  ws->a.resize(pixels);
  ws->u.resize(pixels);
  ws->u_bar.resize(pixels);
  ws->px.assign(pixels, 0.0f);
  ws->py.assign(pixels, 0.0f);
  ws->cost_min.resize(pixels);
  ws->cost_max.resize(pixels);
  for (int pixel = 0; pixel < pixels; ++pixel) {
    const float* c = cost + static_cast<size_t>(pixel) * L;
    int best = 0;
    float lo = c[0], hi = c[0];
    for (int i = 1; i < L; ++i) {
      if (c[i] < lo) {
        lo = c[i];
        best = i;
      }
      hi = std::max(hi, c[i]);
    }
    ws->cost_min[pixel] = lo;
    ws->cost_max[pixel] = hi;
    ws->a[pixel] = planes.U(pixel, best);
    ws->u[pixel] = u_init != nullptr ? (*u_init)[pixel] : ws->a[pixel];
  }
  ws->u_bar = ws->u;
}

// Primal-dual step sizes of the ROF coupling, sigma * tau * ||grad||^2 <= 1
// (||grad||^2 <= 8).
constexpr float kDualStep = 0.5f;     // sigma
constexpr float kPrimalStep = 0.25f;  // tau

// One primal-dual step of the ROF coupling (Chambolle-Pock): dual ascent on
// p projected onto |p| <= w g (ws->tv_weight), then the proximal step of
// (u - a)^2 / (2 theta).
void RofStep(int width, int height, float theta, DepthWorkspace* ws) {
  const float sigma = kDualStep;
  const float tau = kPrimalStep;
  const std::vector<float>& weight = ws->tv_weight;
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      const int pixel = y * width + x;
      const float gx = x + 1 < width ? ws->u_bar[pixel + 1] - ws->u_bar[pixel] : 0.0f;
      const float gy = y + 1 < height ? ws->u_bar[pixel + width] - ws->u_bar[pixel] : 0.0f;
      float qx = ws->px[pixel] + sigma * gx;
      float qy = ws->py[pixel] + sigma * gy;
      const float norm = std::sqrt(qx * qx + qy * qy);
      const float limit = weight[pixel];
      if (norm > limit) {
        const float shrink = limit / norm;
        qx *= shrink;
        qy *= shrink;
      }
      ws->px[pixel] = qx;
      ws->py[pixel] = qy;
    }
  }
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      const int pixel = y * width + x;
      float divergence = 0.0f;
      divergence += (x + 1 < width ? ws->px[pixel] : 0.0f) - (x > 0 ? ws->px[pixel - 1] : 0.0f);
      divergence += (y + 1 < height ? ws->py[pixel] : 0.0f) - (y > 0 ? ws->py[pixel - width] : 0.0f);
      const float previous = ws->u[pixel];
      const float updated = (previous + tau * (divergence + ws->a[pixel] / theta)) / (1.0f + tau / theta);
      ws->u[pixel] = updated;
      ws->u_bar[pixel] = 2.0f * updated - previous;
    }
  }
}

// Point-wise a: the hypothesis of least data cost plus coupling
// (u - a)^2 / (2 theta). Only hypotheses whose coupling cost stays below the
// cost range can win, which bounds the search window. On the `last`
// alternation a is refined below the plane spacing: the vertex of the
// parabola through the neighbouring total energies.
void UpdateAuxiliary(const PlaneSet& planes, int pixels, float theta, bool last, DepthWorkspace* ws) {
  const int L = planes.planes;
  const float* cost = ws->cost.data();
  const float inv_step = 1.0f / planes.step;
  for (int pixel = 0; pixel < pixels; ++pixel) {
    const float* c = cost + static_cast<size_t>(pixel) * L;
    const float u = ws->u[pixel];
    const float reach = std::sqrt(2.0f * theta * (ws->cost_max[pixel] - ws->cost_min[pixel]));
    const float centre = (u - (*planes.base)[pixel]) * inv_step + planes.centre;
    const int lo = std::max(0, static_cast<int>(std::floor(centre - reach * inv_step)));
    const int hi = std::min(L - 1, static_cast<int>(std::ceil(centre + reach * inv_step)));
    const float inv_two_theta = 0.5f / theta;
    int best = std::min(std::max(static_cast<int>(std::lround(centre)), 0), L - 1);
    float best_energy = std::numeric_limits<float>::infinity();
    for (int i = lo; i <= hi; ++i) {
      const float d = u - planes.U(pixel, i);
      const float energy = d * d * inv_two_theta + c[i];
      if (energy < best_energy) {
        best_energy = energy;
        best = i;
      }
    }
    float a = planes.U(pixel, best);
    if (last && best > 0 && best + 1 < L) {
      const float d_minus = u - planes.U(pixel, best - 1);
      const float d_plus = u - planes.U(pixel, best + 1);
      const float e_minus = d_minus * d_minus * inv_two_theta + c[best - 1];
      const float e_plus = d_plus * d_plus * inv_two_theta + c[best + 1];
      const float curvature = e_minus - 2.0f * best_energy + e_plus;
      if (curvature > 1e-9f) {
        const float shift = std::min(0.5f, std::max(-0.5f, 0.5f * (e_minus - e_plus) / curvature));
        a += shift * planes.step;
      }
    }
    ws->a[pixel] = a;
  }
}

// min_u sum_x [ w g(x) |grad u(x)| + C(x, u(x)) ] over the sampled
// hypotheses: the TV-L1 energy of eq:initializationScene with the edge weight
// of eq:regularizingTerm. Solved as in DTAM (Newcombe et al. 2011): the
// auxiliary a(x) carries the (non-convex, sampled) data term and is coupled to
// u by (u - a)^2 / (2 theta); u is a weighted ROF problem (primal-dual
// steps), a a point-wise search; theta decreases geometrically. The last a is
// refined below the plane spacing by a parabola through the neighbouring
// costs. Returns u in ws->u.
void SolveTvL1(const PlaneSet& planes, const cv::Mat& edge_weight, const InitializerOptions& options,
               int width, int height, double theta_start, double theta_end, const std::vector<float>* u_init,
               DepthWorkspace* ws) {
  const int pixels = width * height;
  InitialiseTvL1(planes, pixels, u_init, ws);
  const float tv_weight = static_cast<float>(options.depth_tv_weight);
  std::vector<float>& weight = ws->tv_weight;
  weight.resize(pixels);
  for (int y = 0; y < height; ++y) {
    const float* g = edge_weight.ptr<float>(y);
    for (int x = 0; x < width; ++x) weight[y * width + x] = tv_weight * g[x];
  }
  const int iterations = std::max(2, options.tv_iterations);
  for (int iteration = 0; iteration < iterations; ++iteration) {
    const double progress = static_cast<double>(iteration) / (iterations - 1);
    const float theta = static_cast<float>(theta_start * std::pow(theta_end / theta_start, progress));
    RofStep(width, height, theta, ws);
    UpdateAuxiliary(planes, pixels, theta, iteration + 1 == iterations, ws);
  }
  // A few ROF steps so that u settles on the refined a.
  for (int iteration = 0; iteration < 10; ++iteration) {
    RofStep(width, height, static_cast<float>(theta_end), ws);
  }
}

// P_f^-1 P_f(t_c + delay) for the read-out delay of each of `rows` rows on
// frame f's blur path (SetBlurPath); one identity for a global shutter.
std::vector<SE3> ReadoutIncrements(const std::vector<FrameRecord>& frames,
                                   const std::vector<SE3>& T_world_cam, int f, double readout_time,
                                   int rows) {
  if (!(readout_time > 0.0)) return {SE3()};
  CaptureGeometry path;
  SetBlurPath(T_world_cam, FrameStamps(frames), f, &path);
  const SE3 T_cam_world = T_world_cam[f].Inverse();
  std::vector<SE3> increments(rows);
  for (int y = 0; y < rows; ++y) {
    increments[y] = T_cam_world * PoseAtTime(path, frames[f].stamp + readout_time * y / rows);
  }
  return increments;
}

// Equal-blur image pairs for every frame and neighbour (the Psi_t o B_s and
// Psi_s o B_t of eq:initializationScene) from scale-1 capture operators built
// with the current depths. Psi_s o B_t is B_t blurred by s's blur: s's
// exposure path is moved rigidly to t (same relative motion in the camera
// frame: MoveBlurPath), so t's pixels are swept as s's were.
void BuildBlurredPairs(const std::vector<cv::Mat>& images, const PinholeCamera& camera,
                       const std::vector<FrameRecord>& frames, const std::vector<SE3>& T_world_cam,
                       const std::vector<SE3>& T_world_mid, const std::vector<cv::Mat>& depth,
                       const InitializerOptions& options, int threads, double readout_time,
                       std::vector<std::vector<NeighbourImages>>* pairs) {
  const int num_frames = static_cast<int>(images.size());
  CaptureOperatorOptions capture_options;
  capture_options.scale = 1;
  capture_options.samples = options.capture_samples;
  capture_options.reproject_depth = options.capture_reproject_depth;
  capture_options.num_threads = threads;
  capture_options.transposed_copy = false;  // only Psi is applied (no adjoint): the copy was unused
  CaptureOperatorBuilder builder(capture_options);
  CaptureOperator op;
  const std::vector<double> stamps = FrameStamps(frames);
  // B_frame blurred with the exposure of `kernel_frame`, on frame's grid:
  // kernel_frame's blur path moved rigidly onto frame.
  auto blur_with = [&](int frame, int kernel_frame, cv::Mat* out) {
    CaptureGeometry geometry;
    geometry.camera_hr = camera;
    geometry.depth_hr = depth[frame];
    SetBlurPath(T_world_cam, stamps, kernel_frame, &geometry);
    MoveBlurPath(T_world_cam[frame], frames[frame].stamp, &geometry);
    geometry.exposure = frames[kernel_frame].exposure;
    builder.Build(geometry, &op);
    op.Apply(images[frame], out);
  };
  // B_a through b's blur is the reference of the pair (a, b) and the source
  // of (b, a): each is built once.
  const int k = options.neighbours_per_side;
  std::vector<std::vector<cv::Mat>> blurred(num_frames, std::vector<cv::Mat>(2 * k + 1));
  if (options.blur_aware) {
    for (int a = 0; a < num_frames; ++a) {
      for (int b = std::max(0, a - k); b <= std::min(num_frames - 1, a + k); ++b) {
        if (b != a) blur_with(a, b, &blurred[a][b - a + k]);
      }
    }
  }
  pairs->clear();
  pairs->resize(num_frames);
  for (int t = 0; t < num_frames; ++t) {
    for (int s = t - k; s <= t + k; ++s) {
      if (s < 0 || s >= num_frames || s == t) continue;
      NeighbourImages neighbour;
      neighbour.frame = s;
      if (options.blur_aware) {
        neighbour.reference = blurred[t][s - t + k];
        neighbour.source = blurred[s][t - s + k];
      } else {
        neighbour.reference = images[t];
        neighbour.source = images[s];
      }
      // Where a point of t's shutter-close grid appears in each image: at
      // its blur centroid. In B_t that is its projection at mid-exposure,
      // V = P_t A_t with A_t = P_t^-1 Q_t (Q: mid-exposure pose); the
      // re-blur by s's path moves it on by A_s: V_t|s = P_t A_s A_t, and
      // V_s|t = P_s A_t A_s for the source.
      const SE3 A_t = T_world_cam[t].Inverse() * T_world_mid[t];
      const SE3 A_s = T_world_cam[s].Inverse() * T_world_mid[s];
      const SE3 T_world_ref = options.blur_aware ? T_world_cam[t] * A_s * A_t : T_world_mid[t];
      const SE3 T_world_src = options.blur_aware ? T_world_cam[s] * A_t * A_s : T_world_mid[s];
      // A rolling shutter shifts both by the read-out delay of the row
      // (docs/file_formats.md#rolling-shutter): the camera moves on by
      // each frame's own increment over that delay.
      const std::vector<SE3> delay_t = ReadoutIncrements(frames, T_world_cam, t, readout_time, camera.height);
      const std::vector<SE3> delay_s = ReadoutIncrements(frames, T_world_cam, s, readout_time, camera.height);
      for (size_t y = 0; y < delay_t.size(); ++y) {
        neighbour.to_reference.emplace_back(
            PixelTransfer(camera, (T_world_ref * delay_t[y]).Inverse() * T_world_cam[t]));
        neighbour.to_source.emplace_back(
            PixelTransfer(camera, (T_world_src * delay_s[y]).Inverse() * T_world_cam[t]));
      }
      (*pairs)[t].push_back(std::move(neighbour));
    }
  }
}

// Pyramid levels for the depth passes: up to `wanted`, the coarsest at least
// 24 px on its shorter side.
int PyramidLevels(int width, int height, int wanted) {
  int levels = 1;
  while (levels < wanted && (std::min(width, height) >> levels) >= 24) ++levels;
  return levels;
}

// Depth (1 / rho) of a normalised inverse-depth map; NaN where rho <= 0.
void InverseDepthToDepth(const std::vector<float>& u, int width, int height, double rho_min, double rho_max,
                         cv::Mat* depth) {
  depth->create(height, width, CV_32FC1);
  for (int y = 0; y < height; ++y) {
    float* row = depth->ptr<float>(y);
    for (int x = 0; x < width; ++x) {
      const double rho = rho_min + u[y * width + x] * (rho_max - rho_min);
      row[x] = rho > 1e-12 ? static_cast<float>(1.0 / rho) : std::numeric_limits<float>::quiet_NaN();
    }
  }
}

// u of the previous (half-size) pass up-sampled to width x height: bilinear
// with the pixel-centre rule of docs/file_formats.md#scaling-rule (cv::resize follows it), the odd last
// column / row replicated; *depth follows.
void UpsampleInverseDepth(int width, int height, double rho_min, double rho_max, std::vector<float>* u,
                          cv::Mat* depth) {
  const int coarse_width = depth->cols;
  const int coarse_height = depth->rows;
  const cv::Mat coarse(coarse_height, coarse_width, CV_32FC1, u->data());
  cv::Mat fine;
  cv::resize(coarse, fine, cv::Size(2 * coarse_width, 2 * coarse_height), 0, 0, cv::INTER_LINEAR);
  if (fine.cols != width || fine.rows != height) {
    cv::copyMakeBorder(fine.clone(), fine, 0, height - fine.rows, 0, width - fine.cols, cv::BORDER_REPLICATE);
  }
  u->assign(fine.begin<float>(), fine.end<float>());
  InverseDepthToDepth(*u, width, height, rho_min, rho_max, depth);
}

}  // namespace

void InitializerOptions::Check() const {
  const std::string prefix = "initializer: ";
  CheckAtLeast(prefix + "num_threads", num_threads, 0);
  CheckAtLeast(prefix + "max_features", max_features, 8);
  CheckInInterval(prefix + "feature_quality", feature_quality, 0.0, 1.0, Interval::kOpen);
  CheckAtLeast(prefix + "min_feature_distance_px", min_feature_distance_px, 1.0);
  CheckInRange(prefix + "feature_block_size", feature_block_size, 3, 31);
  CheckInRange(prefix + "klt_window_radius_px", klt_window_radius_px, 2, 32);
  CheckInRange(prefix + "klt_levels", klt_levels, 1, 6);
  CheckAbove(prefix + "klt_max_residual", klt_max_residual, 0.0);
  CheckAbove(prefix + "max_forward_backward_px", max_forward_backward_px, 0.0);
  CheckAbove(prefix + "ransac_threshold_px", ransac_threshold_px, 0.0);
  CheckInInterval(prefix + "ransac_confidence", ransac_confidence, 0.0, 1.0, Interval::kOpen);
  CheckAtLeast(prefix + "min_inliers", min_inliers, 8);
  CheckAtLeast(prefix + "min_parallax_px", min_parallax_px, 0.0);
  CheckAtLeast(prefix + "min_rotation_free_parallax_px", min_rotation_free_parallax_px, 0.0);
  CheckAtLeast(prefix + "min_triangulation_parallax_px", min_triangulation_parallax_px, 0.0);
  CheckAbove(prefix + "pnp_threshold_px", pnp_threshold_px, 0.0);
  CheckAtLeast(prefix + "min_pnp_inliers", min_pnp_inliers, 6);
  CheckAbove(prefix + "ba_loss_px", ba_loss_px, 0.0);
  CheckAbove(prefix + "rotation_prior_px", rotation_prior_px, 0.0);
  CheckAbove(prefix + "fixation_test_z", fixation_test_z, 0.0);
  CheckAbove(prefix + "fixation_test_alone_z", fixation_test_alone_z, 0.0);
  CheckAtLeast(prefix + "track_consistency_z", track_consistency_z, 0.0);
  CheckAtLeast(prefix + "dense_test_block_px", dense_test_block_px, 1);
  CheckAtLeast(prefix + "flow_test_tile_px", flow_test_tile_px, 1);
  CheckAtLeast(prefix + "flow_test_min_gap", flow_test_min_gap, 1);
  CheckAtLeast(prefix + "flow_test_max_gap", flow_test_max_gap, flow_test_min_gap);
  CheckAbove(prefix + "dense_test_z", dense_test_z, 0.0);
  CheckAbove(prefix + "flow_turn_check_z", flow_turn_check_z, 0.0);
  CheckAtLeast(prefix + "ba_max_iterations", ba_max_iterations, 0);
  CheckAtLeast(prefix + "pose_prior_position_sigma", pose_prior_position_sigma, 0.0);
  CheckAtLeast(prefix + "pose_prior_rotation_sigma_deg", pose_prior_rotation_sigma_deg, 0.0);
  try {
    pose_prior.Check();
  } catch (const InputError& error) {
    throw InputError(prefix + "pose_prior: " + error.what());
  }
  CheckInRange(prefix + "capture_samples", capture_samples, 1, 1000);
  CheckInRange(prefix + "neighbours_per_side", neighbours_per_side, 1, 5);
  CheckInRange(prefix + "num_planes", num_planes, 4, 512);
  CheckInRange(prefix + "refine_planes", refine_planes, 3, 256);
  CheckInRange(prefix + "depth_levels", depth_levels, 1, 5);
  CheckAbove(prefix + "refine_band", refine_band, 0.0);
  CheckInRange(prefix + "patch_radius_px", patch_radius_px, 0, 10);
  CheckAbove(prefix + "cost_truncation", cost_truncation, 0.0);
  CheckAtLeast(prefix + "depth_range_margin", depth_range_margin, 0.0);
  CheckAtLeast(prefix + "depth_tv_weight", depth_tv_weight, 0.0);
  CheckAtLeast(prefix + "tv_iterations", tv_iterations, 2);
  CheckAbove(prefix + "theta_start", theta_start, 0.0);
  CheckAbove(prefix + "theta_end", theta_end, 0.0);
  CheckInRange(prefix + "theta_end", theta_end, 0.0, theta_start);
  try {
    edge_weight.Check();
  } catch (const InputError& error) {
    throw InputError(prefix + "edge_weight: " + error.what());
  }
}

namespace {

// Throws InputError unless the options, the camera, the images and the frame
// records fit together.
void CheckInitializerInputs(const std::vector<cv::Mat>& images_lr, const PinholeCamera& camera_lr,
                            const std::vector<FrameRecord>& frames, const InitializerOptions& options) {
  options.Check();
  {
    const std::string problem = camera_lr.Problem();
    if (!problem.empty()) throw InputError("initializer: camera: " + problem);
  }
  const int num_frames = static_cast<int>(images_lr.size());
  if (num_frames < 2) {
    throw InputError("initializer: needs at least 2 frames, got " + std::to_string(num_frames));
  }
  if (frames.size() != images_lr.size()) {
    throw InputError("initializer: " + std::to_string(frames.size()) + " frame records for " +
                     std::to_string(num_frames) + " images");
  }
  for (int t = 0; t < num_frames; ++t) {
    const cv::Mat& image = images_lr[t];
    if (image.empty() || image.depth() != CV_32F || (image.channels() != 1 && image.channels() != 3) ||
        image.cols != camera_lr.width || image.rows != camera_lr.height ||
        image.channels() != images_lr[0].channels()) {
      throw InputError("initializer: image " + std::to_string(t) + " must be float " +
                       std::to_string(camera_lr.width) + "x" + std::to_string(camera_lr.height) +
                       " with 1 or 3 channels, like image 0");
    }
    if (!(frames[t].exposure > 0.0) || (t > 0 && !(frames[t].stamp > frames[t - 1].stamp))) {
      throw InputError("initializer: frame " + std::to_string(t) +
                       ": stamps must increase and exposures be > 0");
    }
  }
  if (camera_lr.width < 16 || camera_lr.height < 16) {
    throw InputError("initializer: images must be at least 16x16");
  }
}

// Stage 1: the tracks; throws when frame 0 has too few corners.
TrackingResult TrackStage(const std::vector<cv::Mat>& gray, const InitializerOptions& options, int threads,
                          std::ostringstream* summary) {
  const int num_frames = static_cast<int>(gray.size());
  const double stage_ms = NowMs();
  TrackingResult tracking = TrackFeatures(gray, options, threads);
  if (tracking.detected[0] < options.min_inliers) {
    throw InitializationError("initialisation: only " + std::to_string(tracking.detected[0]) +
                              " features found in frame 0 (need " + std::to_string(options.min_inliers) +
                              "); is the image blank or untextured?");
  }
  *summary << Format(
      "tracking: %.0f tracks, %.0f in frame 0, %.0f followed into frame 1, %.0f into "
      "the last frame; %.1f ms\n",
      tracking.tracks.size(), tracking.detected[0], tracking.alive[1], tracking.alive[num_frames - 1],
      NowMs() - stage_ms);
  return tracking;
}

// The pairs to start from, in the order they are tried: those sharing at
// least min_inliers tracks whose rotation-free parallax reaches
// min_rotation_free_parallax_px, nearest frames first (smaller gap, then
// earlier). Like the first-pair-with-parallax rule of SLAM initialisers and
// unlike "the largest parallax": the nearest pair shares the most tracks, has
// the most similar blur (Lucas-Kanade's brightness constancy) and the least
// rotation for the prior to absorb, and PnP, triangulation and the bundle
// adjustment widen the baseline over the window anyway. Where frames 0-1
// qualify this is the paper's pair. *best receives the pair of largest
// rotation-free parallax among those with enough tracks (matches = 0 when none
// has), *most_matches the most tracks any pair shares.
std::vector<InitialPair> RankInitialPairs(const PinholeCamera& camera, const InitializerOptions& options,
                                          const std::vector<Track>& tracks, int num_frames, InitialPair* best,
                                          int* most_matches) {
  std::vector<InitialPair> candidates;
  *best = InitialPair();
  *most_matches = 0;
  for (int gap = 1; gap < num_frames; ++gap) {
    for (int a = 0; a + gap < num_frames; ++a) {
      const TwoViewMatches matches = CollectTwoViewMatches(tracks, a, a + gap);
      *most_matches = std::max(*most_matches, matches.Count());
      if (matches.Count() < options.min_inliers) continue;
      InitialPair pair;
      pair.a = a;
      pair.b = a + gap;
      pair.matches = matches.Count();
      // With a narrow field of view even a pure translation is nearly
      // explained by a rotation (see RotationPrior), so what no rotation
      // explains is small; but a pure rotation (or a static camera) leaves
      // only tracking noise, and then nothing carries depth or scale.
      pair.rotation_free_parallax = RotationFreeParallax(camera, matches.points0, matches.points1);
      if (best->matches == 0 || pair.rotation_free_parallax > best->rotation_free_parallax) *best = pair;
      if (pair.rotation_free_parallax >= options.min_rotation_free_parallax_px) candidates.push_back(pair);
    }
  }
  return candidates;
}

// The two-view start from the first candidate of RankInitialPairs whose
// geometry works. Throws NoParallaxError when no pair qualifies but some
// share enough tracks, InitializationError otherwise (the first candidate's
// reason when all fail).
InitialPair InitialiseFromBestPair(const PinholeCamera& camera, const InitializerOptions& options,
                                   int threads, int num_frames, std::vector<Track>* tracks,
                                   SparseStructure* structure) {
  InitialPair best;
  int most_matches = 0;
  const std::vector<InitialPair> candidates =
      RankInitialPairs(camera, options, *tracks, num_frames, &best, &most_matches);
  if (candidates.empty() && best.matches == 0) {
    const int count = CollectTwoViewMatches(*tracks, 0, 1).Count();
    throw InitializationError(
        Format("initialisation: frames 0-1: only %.0f features tracked from frame 0 to "
               "frame 1 (need %.0f); no pair of the %.0f frames shares more than %.0f",
               count, options.min_inliers, num_frames, most_matches));
  }
  if (candidates.empty()) {
    throw NoParallaxError(Format(
        "initialisation: no pair of the %.0f frames has parallax: the best, frames "
        "%.0f-%.0f, leaves %.3f px that no rotation explains (need %.2f px); the "
        "camera must translate, not only rotate",
        num_frames, best.a, best.b, best.rotation_free_parallax, options.min_rotation_free_parallax_px));
  }
  std::string first_error;
  for (const InitialPair& pair : candidates) {
    for (Track& track : *tracks) track.point_id = -1;
    structure->points_world.clear();
    structure->point_inlier.clear();
    try {
      TwoViewInitialisation(camera, options, threads, pair, tracks, structure);
      return pair;
    } catch (const InitializationError& error) {
      if (first_error.empty()) first_error = error.what();
      structure->log.push_back(Format("two-view %.0f-%.0f failed: ", pair.a, pair.b) + error.what());
    }
  }
  throw InitializationError(first_error);
}

// Start pose (T_cam_world) of frame t for PnP: between the pair, the geodesic
// between its cameras; else constant velocity from the two posed neighbours
// on one side (t-1, t-2, else t+1, t+2); else the nearest posed frame.
SE3 PredictPose(const SparseStructure& structure, const std::vector<char>& has_pose, int t) {
  const std::vector<SE3>& T = structure.T_cam_world;
  const int a = structure.reference, b = structure.baseline_frame;
  const int n = static_cast<int>(T.size());
  if (t > a && t < b) {
    const double alpha = static_cast<double>(t - a) / (b - a);
    return InterpolatePose(T[a].Inverse(), T[b].Inverse(), alpha).Inverse();
  }
  if (t >= 2 && has_pose[t - 1] && has_pose[t - 2]) return (T[t - 1] * T[t - 2].Inverse()) * T[t - 1];
  if (t + 2 < n && has_pose[t + 1] && has_pose[t + 2]) return (T[t + 1] * T[t + 2].Inverse()) * T[t + 1];
  for (int d = 1; d < n; ++d) {
    if (t - d >= 0 && has_pose[t - d]) return T[t - d];
    if (t + d < n && has_pose[t + d]) return T[t + d];
  }
  return SE3();
}

// Stages 2-3: the two-view pair, then every other frame by PnP (those
// between the pair, then forward, then backward), triangulating new points
// as frames are added, then all together. The poses are those of
// mid-exposure (T_cam_world) in the pair's gauge. flow_check_follows: the
// caller confirms a kept turn by the flow (the track test then screens at
// fixation_test_z, otherwise it decides at fixation_test_alone_z).
SparseStructure SparseStage(const PinholeCamera& camera_lr, const InitializerOptions& options, int threads,
                            int num_frames, bool track_consistency, bool flow_check_follows,
                            std::vector<Track>* tracks, std::ostringstream* summary,
                            std::optional<SparseStructure>* rejected_turn,
                            std::optional<SparseStructure>* kept_turn_still) {
  double stage_ms = NowMs();
  SparseStructure structure;
  structure.T_cam_world.assign(num_frames, SE3());
  const InitialPair pair =
      InitialiseFromBestPair(camera_lr, options, threads, num_frames, tracks, &structure);
  std::vector<char> has_pose(num_frames, 0);
  has_pose[pair.a] = has_pose[pair.b] = 1;
  std::vector<int> order;
  for (int t = pair.a + 1; t < pair.b; ++t) order.push_back(t);
  for (int t = pair.b + 1; t < num_frames; ++t) order.push_back(t);
  for (int t = pair.a - 1; t >= 0; --t) order.push_back(t);
  for (int t : order) {
    LocaliseFrame(camera_lr, options, t, PredictPose(structure, has_pose, t), *tracks, &structure);
    has_pose[t] = 1;
    TriangulateNewPoints(camera_lr, options, t, has_pose, tracks, &structure);
  }
  *summary << Format("pair: frames %.0f-%.0f (%.0f shared tracks, %.3f px of rotation-free parallax)\n",
                     pair.a, pair.b, pair.matches, pair.rotation_free_parallax);
  for (const std::string& line : structure.log) *summary << line << "\n";
  *summary << Format("two-view + pnp: %.1f ms\n", NowMs() - stage_ms);
  stage_ms = NowMs();
  int observations = 0;
  double rms = BundleAdjust(camera_lr, options, threads, *tracks, &structure, &observations);
  if (track_consistency) {
    rms = LeaveOutInconsistentTracks(camera_lr, options, threads, *tracks, rms, &structure, &observations,
                                     summary);
  }
  const double test_z = flow_check_follows ? options.fixation_test_z : options.fixation_test_alone_z;
  rms = SelectFixationTurn(camera_lr, options, test_z, threads, *tracks, rms, &structure, &observations,
                           summary, rejected_turn, kept_turn_still);
  *summary << Format("bundle adjustment: %.0f points, %.0f observations, rms %.3f px; %.1f ms\n",
                     structure.points_world.size(), observations, rms, NowMs() - stage_ms);
  return structure;
}

// Mid-exposure camera of frame f (T_world_mid) `delay` later: on the
// quadratic through the mid-exposure poses of f-1, f and f+1 (the first
// frame: 0, 1, 2), the path of the tracks' rows and of the interior frames'
// shutter close (MidExposureToShutterClose); on the geodesic through f-1
// and f for the last frame, and with fewer than 3 frames. (The capture
// model's interior paths are cubics through f-2 .. f+1, BlurPathFrames; a
// cubic here raised the hand-held ATE: BENCHMARKS.md "A cubic blur path for
// the interior frames".)
double MidExposureTime(const FrameRecord& frame) {
  return frame.stamp - 0.5 * frame.exposure;
}

SE3 RowPose(const std::vector<FrameRecord>& frames, const std::vector<SE3>& T_world_mid, int f, double delay) {
  const int num_frames = static_cast<int>(frames.size());
  const auto mid = [&frames](int t) { return MidExposureTime(frames[t]); };
  if (num_frames >= 3 && f + 1 < num_frames) {
    const int a = f > 0 ? f - 1 : f + 2;
    return PoseOnQuadraticPath(T_world_mid[a], mid(a), T_world_mid[f + 1], mid(f + 1), T_world_mid[f], mid(f),
                               mid(f) + delay);
  }
  const int n = f > 0 ? f - 1 : 1;
  return PoseAtTime(T_world_mid[n], mid(n), T_world_mid[f], mid(f), mid(f) + delay);
}

// Rolling shutter (docs/file_formats.md#rolling-shutter): a point tracked at
// LR row v of frame f was seen v * readout / H after row 0, by a camera that
// had moved on. The bundle adjustment models a global shutter, so every
// observation is moved to where frame f's mid-exposure camera (row 0) sees
// its point, by the motion the current poses predict (the pose at mid_f +
// delay on the path through the neighbouring mid-exposure poses,
// eq:interpolatingP), and the adjustment runs again; twice, as the
// corrections follow the poses. The tracks become the corrected ones.
// Returns the last adjustment's RMS error.
double CorrectRollingShutter(const PinholeCamera& camera, const InitializerOptions& options, int threads,
                             const std::vector<FrameRecord>& frames, double readout_time,
                             std::vector<Track>* tracks, SparseStructure* structure,
                             std::ostringstream* summary) {
  const double start_ms = NowMs();
  const int num_frames = static_cast<int>(frames.size());
  const std::vector<Track> observed = *tracks;
  double rms = 0.0, mean_shift = 0.0;
  int observations = 0;
  for (int round = 0; round < 2; ++round) {
    std::vector<SE3> T_world_mid(num_frames);
    for (int t = 0; t < num_frames; ++t) T_world_mid[t] = structure->T_cam_world[t].Inverse();
    double shift_sum = 0.0;
    int shifted = 0;
    for (size_t i = 0; i < observed.size(); ++i) {
      const Track& track = observed[i];
      if (track.point_id < 0 || !structure->point_inlier[track.point_id]) continue;
      const Eigen::Vector3d& point = structure->points_world[track.point_id];
      for (int f = track.first_frame; f <= track.LastFrame(); ++f) {
        const double delay = readout_time * track.At(f).y / camera.height;
        const SE3 T_world_row = RowPose(frames, T_world_mid, f, delay);
        const Eigen::Vector3d p_row = T_world_row.Inverse() * point;
        const Eigen::Vector3d p_mid = structure->T_cam_world[f] * point;
        if (!(p_row.z() > 1e-9) || !(p_mid.z() > 1e-9)) continue;
        const Eigen::Vector2d shift = camera.Project(p_mid) - camera.Project(p_row);
        cv::Point2f& corrected = (*tracks)[i].points[f - track.first_frame];
        corrected = track.At(f) + cv::Point2f(static_cast<float>(shift.x()), static_cast<float>(shift.y()));
        shift_sum += shift.norm();
        ++shifted;
      }
    }
    mean_shift = shift_sum / std::max(1, shifted);
    rms = BundleAdjust(camera, options, threads, *tracks, structure, &observations);
  }
  *summary << Format(
      "rolling shutter (readout %.4f s): observations moved %.2f px on average; rms %.3f px; %.1f ms\n",
      readout_time, mean_shift, rms, NowMs() - start_ms);
  return rms;
}

}  // namespace

// RowPose half an exposure after mid-exposure: the quadratic through the
// mid-exposure poses of t-1, t and t+1 interpolates there (Lagrange weights
// -0.12 / 0.84 / 0.28 at an exposure of 0.8 frame intervals); the last frame
// extrapolates the geodesic through t-1 and t (eq:interpolatingP), and frame
// 0 stays on the geodesic through frames 0 and 1 (the variant measured in
// BENCHMARKS.md "The first frame's blur on the curve").
std::vector<SE3> MidExposureToShutterClose(const std::vector<FrameRecord>& frames,
                                           const std::vector<SE3>& T_world_mid) {
  if (frames.size() < 2 || T_world_mid.size() != frames.size()) {
    throw InputError("MidExposureToShutterClose: needs >= 2 frames and one pose per frame");
  }
  const int num_frames = static_cast<int>(frames.size());
  std::vector<SE3> T_world_cam(num_frames);
  for (int t = 0; t < num_frames; ++t) {
    T_world_cam[t] = t > 0 ? RowPose(frames, T_world_mid, t, 0.5 * frames[t].exposure)
                           : PoseAtTime(T_world_mid[0], MidExposureTime(frames[0]), T_world_mid[1],
                                        MidExposureTime(frames[1]), frames[0].stamp);
  }
  return T_world_cam;
}

namespace {

// Each frame's pose prior at its mid-exposure (t_c - exposure / 2), the time
// of the sparse poses: on the prior's geodesic through frames t-1 and t
// (frame 0: 0 and 1, extrapolated), an interpolation between the stamps
// for every other frame; the frame's own prior pose where that neighbour
// has none.
std::vector<std::optional<SE3>> PriorAtMidExposure(const std::vector<FrameRecord>& frames,
                                                   const std::vector<std::optional<SE3>>& T_prior_cam) {
  const int num_frames = static_cast<int>(frames.size());
  std::vector<std::optional<SE3>> T_prior_mid(num_frames);
  for (int t = 0; t < num_frames; ++t) {
    if (!T_prior_cam[t]) continue;
    const int a = t > 0 ? t - 1 : 0;
    const int b = t > 0 ? t : 1;
    const double mid = MidExposureTime(frames[t]);
    T_prior_mid[t] = T_prior_cam[a] && T_prior_cam[b] ? PoseAtTime(*T_prior_cam[a], frames[a].stamp,
                                                                   *T_prior_cam[b], frames[b].stamp, mid)
                                                      : *T_prior_cam[t];
  }
  return T_prior_mid;
}

// Stage 3b, with a pose prior (InitializerOptions::pose_prior_position_sigma):
// the bundle-adjusted mid-exposure poses are aligned to the prior's by a
// robust Sim(3) (AlignToPrior), the structure is carried into the prior's
// frame by it (kappa scales inversely), and the bundle adjustment runs again
// with the prior centres (and orientations, with pose_prior_rotation_sigma_deg;
// kappa then fitted) of the frames that agree with the alignment. The
// structure is then in prior units. Unchanged when the alignment fails (too
// little prior translation, too few agreeing frames: said in the summary).
void AdjustToPosePrior(const PinholeCamera& camera, const InitializerOptions& options, int threads,
                       const std::vector<FrameRecord>& frames, const std::vector<std::optional<SE3>>& T_prior_cam,
                       const std::vector<Track>& tracks, SparseStructure* structure, std::ostringstream* summary) {
  if (T_prior_cam.empty() || options.pose_prior_position_sigma == 0.0) return;
  const double start_ms = NowMs();
  const std::vector<std::optional<SE3>> T_prior_mid = PriorAtMidExposure(frames, T_prior_cam);
  std::vector<int> frame_of;
  std::vector<SE3> estimated, prior;
  for (size_t t = 0; t < T_prior_mid.size(); ++t) {
    if (!T_prior_mid[t]) continue;
    frame_of.push_back(static_cast<int>(t));
    estimated.push_back(structure->T_cam_world[t].Inverse());
    prior.push_back(*T_prior_mid[t]);
  }
  const PriorAlignment alignment = AlignToPrior(estimated, prior, options.pose_prior);
  if (!alignment.valid) {
    *summary << "pose prior: not used by the bundle adjustment (" << alignment.note << ")\n";
    return;
  }
  const Sim3& to_prior = alignment.estimate_to_prior;
  for (SE3& T_cam_world : structure->T_cam_world) {
    T_cam_world = TransformPose(to_prior, T_cam_world.Inverse()).Inverse();
  }
  for (Eigen::Vector3d& point : structure->points_world) {
    point = TransformPoint(to_prior, point);
  }
  structure->turn_rate /= to_prior.scale;
  structure->prior_sigma = options.pose_prior_position_sigma;
  structure->prior_centres.assign(structure->T_cam_world.size(), std::nullopt);
  structure->prior_orientations.assign(structure->T_cam_world.size(), Eigen::Matrix3d::Identity());
  structure->prior_rotation_sigma = options.pose_prior_rotation_sigma_deg * M_PI / 180.0;
  // The prior's orientations observe the turn that RotationPrior otherwise
  // assumes (kappa): it is fitted to them.
  if (structure->prior_rotation_sigma > 0.0) structure->fit_turn_rate = true;
  for (int i : alignment.inlier_frames) {
    structure->prior_centres[frame_of[i]] = prior[i].translation();
    structure->prior_orientations[frame_of[i]] = prior[i].rotation().transpose();
  }
  int observations = 0;
  const double rms = BundleAdjust(camera, options, threads, tracks, structure, &observations);
  double squares = 0.0;
  for (int i : alignment.inlier_frames) {
    squares += (structure->T_cam_world[frame_of[i]].Inverse().translation() - prior[i].translation()).squaredNorm();
  }
  double angle_squares = 0.0;
  for (int i : alignment.inlier_frames) {
    const Eigen::Matrix3d R_cam_prior = structure->T_cam_world[frame_of[i]].rotation() * prior[i].rotation();
    angle_squares += SO3Log(R_cam_prior).squaredNorm();
  }
  const int inliers = std::max(1, alignment.inliers);
  *summary << Format("pose prior: Sim(3) scale %.4g from %.0f of %.0f frames (rms %.3g); ", to_prior.scale,
                     alignment.inliers, alignment.used, alignment.rms)
           << Format("bundle adjustment with their centres (sigma %.3g) and orientations (sigma %.3g deg): ",
                     options.pose_prior_position_sigma, options.pose_prior_rotation_sigma_deg)
           << Format("rms %.3f px, centres %.3g and orientations %.3g deg from the prior (rms); prior units "
                     "from here on; %.1f ms\n",
                     rms, std::sqrt(squares / inliers), std::sqrt(angle_squares / inliers) * 180.0 / M_PI,
                     NowMs() - start_ms);
}

// The tracks follow the blurred patterns, i.e. the blur centroids: the
// sparse poses are those of mid-exposure, t_c - exposure / 2 (exact for
// motion that is linear in the image over an exposure). The output poses
// are at the shutter close t_c (docs/file_formats.md#exposure), by
// MidExposureToShutterClose (the quadratic through the neighbours'
// mid-exposure poses; eq:interpolatingP at the ends). World = camera 0 at t_c
// (re-anchored here; the points follow); the scale stays the pair's
// (|c_b - c_a| = 1 at mid-exposure) until NormaliseGauge.
void MoveToShutterClose(const std::vector<FrameRecord>& frames, SparseStructure* structure,
                        std::vector<SE3>* T_world_cam, std::vector<SE3>* T_world_mid,
                        std::ostringstream* summary) {
  const int num_frames = static_cast<int>(frames.size());
  T_world_mid->resize(num_frames);
  for (int t = 0; t < num_frames; ++t) (*T_world_mid)[t] = structure->T_cam_world[t].Inverse();
  *T_world_cam = MidExposureToShutterClose(frames, *T_world_mid);
  const SE3 T_new_old = (*T_world_cam)[0].Inverse();
  for (int t = 0; t < num_frames; ++t) {
    (*T_world_cam)[t] = T_new_old * (*T_world_cam)[t];
    (*T_world_mid)[t] = T_new_old * (*T_world_mid)[t];
  }
  for (auto& point : structure->points_world) point = T_new_old * point;
  *summary << Format(
      "poses moved from mid-exposure to shutter close: %.3f (frame 0), %.3f (last) pair "
      "baselines (or prior units)\n",
      ((*T_world_mid)[0].translation() - (*T_world_cam)[0].translation()).norm(),
      ((*T_world_mid)[num_frames - 1].translation() - (*T_world_cam)[num_frames - 1].translation()).norm());
}

// The output gauge (docs/file_formats.md#monocular-scale): the monocular
// scale such that the median of all valid LR depths of the window (every
// frame's depth_lr pixels > 0) is exactly 1; depths and camera centres are
// divided by that median (world = camera 0 at t_c stays). Throws
// InitializationError when no depth is valid.
void NormaliseGauge(InitialStructure* result, std::ostringstream* summary) {
  std::vector<float> values;
  size_t total = 0;
  for (const cv::Mat& depth : result->depth_lr) total += depth.total();
  values.reserve(total);
  for (const cv::Mat& depth : result->depth_lr) {
    for (int y = 0; y < depth.rows; ++y) {
      const float* row = depth.ptr<float>(y);
      for (int x = 0; x < depth.cols; ++x) {
        if (row[x] > 0.0f && std::isfinite(row[x])) values.push_back(row[x]);
      }
    }
  }
  if (values.empty()) throw InitializationError("initialisation: no valid depth (degenerate geometry)");
  const size_t middle = values.size() / 2;
  std::nth_element(values.begin(), values.begin() + middle, values.end());
  const double median = values[middle];
  for (cv::Mat& depth : result->depth_lr) depth *= 1.0 / median;
  for (SE3& T : result->T_world_cam) T = SE3(T.rotation(), T.translation() / median);
  *summary << Format("gauge: world = camera 0 at t_c, median depth 1 (%.4g pair baselines, or prior units)\n",
                     median);
}

// Inverse-depth range of each frame's sweep and its median depth (the start
// of the first pass), from the triangulated points it sees.
struct DepthRanges {
  std::vector<double> rho_min, rho_max, median_depth;
};

DepthRanges ComputeDepthRanges(const std::vector<Track>& tracks, const SparseStructure& structure,
                               const std::vector<SE3>& T_world_cam, const InitializerOptions& options) {
  const int num_frames = static_cast<int>(T_world_cam.size());
  DepthRanges ranges;
  ranges.rho_min.resize(num_frames);
  ranges.rho_max.resize(num_frames);
  ranges.median_depth.resize(num_frames);
  std::vector<double> all_depths;
  std::vector<std::vector<double>> frame_depths(num_frames);
  for (const Track& track : tracks) {
    if (track.point_id < 0 || !structure.point_inlier[track.point_id]) continue;
    for (int f = track.first_frame; f <= track.LastFrame(); ++f) {
      const double z = (T_world_cam[f].Inverse() * structure.points_world[track.point_id]).z();
      if (z > 0.0) {
        frame_depths[f].push_back(z);
        all_depths.push_back(z);
      }
    }
  }
  if (all_depths.size() < 8) {
    throw InitializationError(
        "initialisation: too few triangulated points in front of the "
        "cameras (degenerate geometry)");
  }
  for (int t = 0; t < num_frames; ++t) {
    const std::vector<double>& depths = frame_depths[t].size() >= 8 ? frame_depths[t] : all_depths;
    const double near = Percentile(depths, 0.02);
    const double far = Percentile(depths, 0.98);
    ranges.median_depth[t] = Median(depths);
    const double rho_near = 1.0 / near, rho_far = 1.0 / far;
    // At least +-10 % of the median: a near-planar scene still gets a range.
    const double margin =
        std::max(options.depth_range_margin * (rho_near - rho_far), 0.1 / ranges.median_depth[t]);
    ranges.rho_max[t] = rho_near + margin;
    ranges.rho_min[t] = std::max(rho_far - margin, 0.5 * rho_far);
  }
  return ranges;
}

// One level of the coarse-to-fine depth passes: the input box-downsampled by
// `factor` (an odd last column / row dropped), its camera and the edge
// weights g_t of eq:regularizingTerm.
struct DepthLevel {
  int factor = 1;
  int width = 0;
  int height = 0;
  PinholeCamera camera;
  std::vector<cv::Mat> images, edge_weight;
};

DepthLevel MakeDepthLevel(const std::vector<cv::Mat>& images, const PinholeCamera& camera_lr, int factor,
                          const InitializerOptions& options) {
  const int num_frames = static_cast<int>(images.size());
  DepthLevel level;
  level.factor = factor;
  level.width = camera_lr.width / factor;
  level.height = camera_lr.height / factor;
  level.camera = PinholeCamera(level.width * factor, level.height * factor, camera_lr.fx, camera_lr.fy,
                               camera_lr.cx, camera_lr.cy)
                     .Downscaled(factor);
  level.images.resize(num_frames);
  level.edge_weight.resize(num_frames);
  for (int t = 0; t < num_frames; ++t) {
    const cv::Mat cropped = images[t](cv::Rect(0, 0, level.width * factor, level.height * factor));
    level.images[t] = factor == 1 ? images[t] : DownsampleBox(cropped.clone(), factor);
    level.edge_weight[t] = EdgeWeight(level.images[t], options.edge_weight);
  }
  return level;
}

// Wall and thread time of the depth passes, for the summary.
struct DepthTimings {
  double blur_ms = 0.0, sweep_ms = 0.0, cost_thread_ms = 0.0, tv_thread_ms = 0.0;
};

// Data term of eq:initializationScene at the TV-L1 solution ws.u (the
// sampled hypothesis nearest to it), per pixel of one frame.
void SolutionDataCost(const PlaneSet& planes, int width, int height, const DepthWorkspace& ws,
                      cv::Mat* cost_map) {
  const int L = planes.planes;
  cost_map->create(height, width, CV_32FC1);
  float* out = cost_map->ptr<float>();
  for (int pixel = 0; pixel < width * height; ++pixel) {
    const float plane = (ws.u[pixel] - (*planes.base)[pixel]) / planes.step + planes.centre;
    const int nearest = std::min(std::max(static_cast<int>(std::lround(plane)), 0), L - 1);
    out[pixel] = ws.cost[static_cast<size_t>(pixel) * L + nearest];
  }
}

// One pass over every frame (in parallel): the cost volume of the pass's
// hypotheses (the whole range at pass 0, else a band of `span` around the
// up-sampled estimate), TV-L1, and the depth that follows. u[t] and depth[t]
// are read as the previous estimate and replaced.
void DepthPass(const DepthLevel& level, int pass, double span,
               const std::vector<std::vector<NeighbourImages>>& pairs, const DepthRanges& ranges,
               const InitializerOptions& options, int threads, std::vector<DepthWorkspace>* workspaces,
               std::vector<std::vector<float>>* u, std::vector<cv::Mat>* depth, DepthTimings* timings,
               std::vector<cv::Mat>* solution_cost) {
  const int num_frames = static_cast<int>(depth->size());
  const std::vector<float> zero_base(static_cast<size_t>(level.width) * level.height, 0.0f);
#pragma omp parallel for schedule(dynamic, 1) num_threads(threads)
  for (int t = 0; t < num_frames; ++t) {
    DepthWorkspace& ws = (*workspaces)[omp_get_thread_num()];
    PlaneSet planes;
    planes.rho_min = ranges.rho_min[t];
    planes.rho_max = ranges.rho_max[t];
    if (pass == 0) {
      planes.planes = options.num_planes;
      planes.centre = 0.0f;
      planes.step = 1.0f / (options.num_planes - 1);
      planes.base = &zero_base;
    } else {
      planes.planes = options.refine_planes;
      planes.centre = 0.5f * (options.refine_planes - 1);
      planes.step = static_cast<float>(span / (options.refine_planes - 1));
      planes.base = &(*u)[t];
    }
    const double sweep_start = NowMs();
    ComputeCostVolume(pairs[t], planes, options, level.width, level.height, &ws);
    const double tv_start = NowMs();
    SolveTvL1(planes, level.edge_weight[t], options, level.width, level.height,
              options.theta_start * span * span, options.theta_end * span * span,
              pass == 0 ? nullptr : &(*u)[t], &ws);
    const double tv_end = NowMs();
    if (solution_cost != nullptr) {
      SolutionDataCost(planes, level.width, level.height, ws, &(*solution_cost)[t]);
    }
#pragma omp critical(initializer_timers)
    {
      timings->cost_thread_ms += tv_start - sweep_start;
      timings->tv_thread_ms += tv_end - tv_start;
    }
    (*u)[t] = ws.u;
    InverseDepthToDepth((*u)[t], level.width, level.height, ranges.rho_min[t], ranges.rho_max[t],
                        &(*depth)[t]);
  }
}

// Stage 4: eq:initializationScene per frame, coarse to fine over an image
// pyramid: pass 0 sweeps the whole range on the coarsest level (global, so no
// local minima to escape), each finer pass re-builds the blur operators with
// the depths so far (Psi depends on D_t) and sweeps a narrow band around the
// up-sampled estimate. Returns the LR depth maps of the input size.
std::vector<cv::Mat> DepthStage(const std::vector<cv::Mat>& images, const PinholeCamera& camera_lr,
                                const std::vector<FrameRecord>& frames, const std::vector<SE3>& T_world_cam,
                                const std::vector<SE3>& T_world_mid, const DepthRanges& ranges,
                                const InitializerOptions& options, int threads, double readout_time,
                                std::ostringstream* summary, std::vector<cv::Mat>* solution_cost = nullptr) {
  const int num_frames = static_cast<int>(images.size());
  const int width = camera_lr.width;
  const int height = camera_lr.height;
  const int num_levels = PyramidLevels(width, height, options.depth_levels);
  std::vector<std::vector<float>> u(num_frames);  // normalised inverse depth
  std::vector<cv::Mat> depth(num_frames);
  DepthTimings timings;
  std::vector<std::vector<NeighbourImages>> pairs;
  std::vector<DepthWorkspace> workspaces(threads);
  double span = 1.0;  // u-range covered by a pass's hypotheses
  for (int pass = 0; pass < num_levels; ++pass) {
    const DepthLevel level = MakeDepthLevel(images, camera_lr, 1 << (num_levels - 1 - pass), options);
    for (int t = 0; t < num_frames; ++t) {
      if (pass == 0) {
        u[t].clear();
        depth[t] = cv::Mat(level.height, level.width, CV_32FC1,
                           cv::Scalar(static_cast<float>(ranges.median_depth[t])));
      } else {
        UpsampleInverseDepth(level.width, level.height, ranges.rho_min[t], ranges.rho_max[t], &u[t],
                             &depth[t]);
      }
    }
    double stage_ms = NowMs();
    BuildBlurredPairs(level.images, level.camera, frames, T_world_cam, T_world_mid, depth, options, threads,
                      readout_time, &pairs);
    timings.blur_ms += NowMs() - stage_ms;
    stage_ms = NowMs();
    if (pass > 0) {
      span =
          2.0 * options.refine_band * span / ((pass == 1 ? options.num_planes : options.refine_planes) - 1);
    }
    if (solution_cost != nullptr) solution_cost->resize(num_frames);
    DepthPass(level, pass, span, pairs, ranges, options, threads, &workspaces, &u, &depth, &timings,
              solution_cost);
    timings.sweep_ms += NowMs() - stage_ms;
    *summary << Format(
        "depth pass %.0f: %.0fx%.0f px, %.0f hypotheses over %.4f of the "
        "inverse-depth range\n",
        pass, level.width, level.height, pass == 0 ? options.num_planes : options.refine_planes, span);
  }
  // The finest pass may have dropped an odd last column / row: replicate.
  for (int t = 0; t < num_frames; ++t) {
    if (depth[t].cols != width || depth[t].rows != height) {
      cv::copyMakeBorder(depth[t].clone(), depth[t], 0, height - depth[t].rows, 0, width - depth[t].cols,
                         cv::BORDER_REPLICATE);
    }
  }
  *summary << Format(
      "depth: blur-aware pairs %.1f ms, sweep + TV-L1 %.1f ms (thread time: cost "
      "volumes %.1f ms, TV-L1 %.1f ms)\n",
      timings.blur_ms, timings.sweep_ms, timings.cost_thread_ms, timings.tv_thread_ms);
  return depth;
}

// Continuous images (the capture operator reads them flat) and gray copies.
void ContinuousAndGray(const std::vector<cv::Mat>& images_lr, std::vector<cv::Mat>* images,
                       std::vector<cv::Mat>* gray) {
  const size_t num_frames = images_lr.size();
  images->resize(num_frames);
  gray->resize(num_frames);
  for (size_t t = 0; t < num_frames; ++t) {
    (*images)[t] = images_lr[t].isContinuous() ? images_lr[t] : images_lr[t].clone();
    if ((*images)[t].channels() == 3) {
      cv::cvtColor((*images)[t], (*gray)[t], cv::COLOR_BGR2GRAY);
    } else {
      (*gray)[t] = (*images)[t];
    }
  }
}

// The matched points of the tracks that see both frames a and b.
struct PairMatches {
  std::vector<cv::Point2f> points_a, points_b;
  int Count() const { return static_cast<int>(points_a.size()); }
};

PairMatches CollectPairMatches(const std::vector<Track>& tracks, int a, int b) {
  PairMatches matches;
  for (const Track& track : tracks) {
    if (track.Sees(a) && track.Sees(b)) {
      matches.points_a.push_back(track.At(a));
      matches.points_b.push_back(track.At(b));
    }
  }
  return matches;
}

// Mid-exposure orientation of frame t (R_world_mid of the earlier frames
// known): the rotation relative to the earliest frame r that shares at least
// min_inliers tracks with t (the least chaining), by FitRotationRansac.
// There is no photometric refinement: an ECC homography (cv::findTransformECC,
// MOTION_HOMOGRAPHY, started from K R K^-1, projected back to the nearest
// rotation) was tried and, on the 6-frame `rotate` Dolls sequence of
// RotationOnlyMotionTest, moved every estimate by 1.2-1.4 px and raised the
// errors from <= 0.006 deg to 0.07-0.11 deg; the KLT tracks (hundreds per
// pair, rms <= 0.06 px) already pin the 3 parameters.
Eigen::Matrix3d RegisterRotationOnlyFrame(const PinholeCamera& camera, const InitializerOptions& options,
                                          const std::vector<Track>& tracks,
                                          const std::vector<Eigen::Matrix3d>& R_world_mid, int t,
                                          std::ostringstream* summary) {
  int reference = 0;
  PairMatches matches;
  int most_shared = 0;
  for (; reference < t; ++reference) {
    matches = CollectPairMatches(tracks, reference, t);
    most_shared = std::max(most_shared, matches.Count());
    if (matches.Count() >= options.min_inliers) break;
  }
  if (reference == t) {
    throw InitializationError("initialisation: frame " + std::to_string(t) + " shares at most " +
                              std::to_string(most_shared) + " tracks with an earlier frame (need " +
                              std::to_string(options.min_inliers) + ")");
  }
  RotationFit fit =
      FitRotationRansac(camera, matches.points_a, matches.points_b, options.ransac_threshold_px);
  if (fit.inliers < options.min_inliers) {
    throw InitializationError(
        Format("initialisation: frames %.0f-%.0f: only %.0f of %.0f matches fit one rotation "
               "(need %.0f)",
               reference, t, fit.inliers, matches.Count(), options.min_inliers));
  }
  *summary << Format("rotation %.0f-%.0f: %.0f of %.0f matches, rms %.3f px, %.2f deg\n", reference, t,
                     fit.inliers, matches.Count(), fit.rms_px,
                     Eigen::AngleAxisd(fit.R_1_0).angle() * 180.0 / M_PI);
  return R_world_mid[reference] * fit.R_1_0.transpose();  // R_world_t = R_world_r R_r_t
}

// Stage 1 of both entry points: the inputs checked, continuous and gray
// copies of the frames, and the KLT tracks.
struct TrackedWindow {
  int threads = 1;
  std::vector<cv::Mat> images, gray;
  TrackingResult tracking;
};

TrackedWindow TrackWindow(const std::vector<cv::Mat>& images_lr, const PinholeCamera& camera_lr,
                          const std::vector<FrameRecord>& frames, const InitializerOptions& options,
                          std::ostringstream* summary) {
  CheckInitializerInputs(images_lr, camera_lr, frames, options);
  TrackedWindow window;
  window.threads = ResolveThreads(options.num_threads);
  ContinuousAndGray(images_lr, &window.images, &window.gray);
  window.tracking = TrackStage(window.gray, options, window.threads, summary);
  return window;
}

// Runs `body`; an OpenCV assertion on degenerate input the checks did not
// foresee becomes an InitializationError of one line, prefixed by `what`.
template <typename Body>
auto WithOpenCvErrorsAsInitializationErrors(const std::string& what, const Body& body) {
  try {
    return body();
  } catch (const cv::Exception& error) {
    std::string message = error.err.empty() ? std::string(error.what()) : error.err;
    std::replace(message.begin(), message.end(), '\n', ' ');
    throw InitializationError(what + message + ")");
  }
}

RotationOnlyMotion EstimateRotationOnlyMotionUnguarded(const std::vector<cv::Mat>& images_lr,
                                                       const PinholeCamera& camera_lr,
                                                       const std::vector<FrameRecord>& frames,
                                                       const InitializerOptions& options) {
  const double start_ms = NowMs();
  std::ostringstream summary;
  const TrackedWindow window = TrackWindow(images_lr, camera_lr, frames, options, &summary);
  const TrackingResult& tracking = window.tracking;
  const int num_frames = static_cast<int>(images_lr.size());
  std::vector<Eigen::Matrix3d> R_world_mid(num_frames, Eigen::Matrix3d::Identity());
  for (int t = 1; t < num_frames; ++t) {
    R_world_mid[t] = RegisterRotationOnlyFrame(camera_lr, options, tracking.tracks, R_world_mid, t, &summary);
  }
  // Tracks follow blur centroids: mid-exposure orientations, moved to
  // t_c exactly as the full poses are (translations stay 0).
  std::vector<SE3> T_world_mid(num_frames);
  for (int t = 0; t < num_frames; ++t) T_world_mid[t] = SE3(R_world_mid[t], Eigen::Vector3d::Zero());
  const std::vector<SE3> T_world_cam = MidExposureToShutterClose(frames, T_world_mid);
  RotationOnlyMotion result;
  const Eigen::Matrix3d R_new_old = T_world_cam[0].rotation().transpose();  // world = camera 0 at t_c
  for (int t = 0; t < num_frames; ++t) result.R_world_cam.push_back(R_new_old * T_world_cam[t].rotation());
  summary << Format("total: %.1f ms", NowMs() - start_ms);
  result.summary = summary.str();
  return result;
}

// Paired comparison of two solutions' data costs on the same frames' grids
// (before minus after): the per-pixel differences are averaged over blocks
// of block x block px and over the frames (a block location is one sample:
// neighbouring pixels share patches and blur, and the frames see the same
// scene), and the mean of the samples is compared with its standard error.
struct DataCostComparison {
  double mean = 0.0;      // mean difference per pixel
  double relative = 0.0;  // mean / mean cost before
  double z = 0.0;         // mean / its standard error
  int blocks = 0;
  int maps = 0;  // cost maps compared (frames, or the flow test's pairs)
};

DataCostComparison CompareDataCosts(const std::vector<cv::Mat>& before, const std::vector<cv::Mat>& after,
                                    int block) {
  DataCostComparison result;
  if (before.empty() || before.size() != after.size()) return result;
  result.maps = static_cast<int>(before.size());
  const int width = before[0].cols, height = before[0].rows;
  const int bx = std::max(1, width / block), by = std::max(1, height / block);
  std::vector<double> sums(static_cast<size_t>(bx) * by, 0.0);
  double total_before = 0.0, count = 0.0;
  for (size_t t = 0; t < before.size(); ++t) {
    for (int y = 0; y < by * block && y < height; ++y) {
      const float* b = before[t].ptr<float>(y);
      const float* a = after[t].ptr<float>(y);
      for (int x = 0; x < bx * block && x < width; ++x) {
        sums[static_cast<size_t>(y / block) * bx + x / block] += b[x] - a[x];
        total_before += b[x];
        count += 1.0;
      }
    }
  }
  const double per_sample = count / sums.size();
  double mean = 0.0, squares = 0.0;
  for (double& sum : sums) {
    sum /= per_sample;
    mean += sum;
  }
  mean /= sums.size();
  for (double sum : sums) squares += (sum - mean) * (sum - mean);
  const double n = static_cast<double>(sums.size());
  const double standard_error = std::sqrt(squares / std::max(1.0, n - 1.0) / n);
  result.mean = mean;
  result.relative = total_before > 0.0 ? mean * count / total_before : 0.0;
  result.z = standard_error > 0.0 ? mean / standard_error : 0.0;
  result.blocks = static_cast<int>(n);
  return result;
}

// Distance (LR px) of each flow end point x + flow(x) in frame s from the
// epipolar line of x (frame t's pixel) under a structure's mid-exposure
// poses; 0 where the end point leaves the image or `consistent` is 0 (no
// sample); capped at `cap` (flow failures: occlusions, textureless areas).
// Forward-backward consistency of a flow pair (Sundaram, Brox and Keutzer,
// ECCV 2010): 255 where |w_f(x) + w_b(x + w_f(x))|^2 < 0.01 (|w_f|^2 +
// |w_b|^2) + 0.5 px^2, w_b bilinearly sampled; 0 elsewhere and where the
// end point leaves the image.
cv::Mat ForwardBackwardConsistent(const cv::Mat& forward, const cv::Mat& backward) {
  cv::Mat map(forward.size(), CV_32FC2);
  for (int y = 0; y < forward.rows; ++y) {
    const cv::Point2f* f = forward.ptr<cv::Point2f>(y);
    cv::Point2f* m = map.ptr<cv::Point2f>(y);
    for (int x = 0; x < forward.cols; ++x) m[x] = cv::Point2f(x + f[x].x, y + f[x].y);
  }
  cv::Mat backward_at_end;
  cv::remap(backward, backward_at_end, map, cv::noArray(), cv::INTER_LINEAR, cv::BORDER_CONSTANT,
            cv::Scalar(std::numeric_limits<float>::quiet_NaN(), std::numeric_limits<float>::quiet_NaN()));
  cv::Mat consistent(forward.size(), CV_8UC1, cv::Scalar(0));
  for (int y = 0; y < forward.rows; ++y) {
    const cv::Point2f* f = forward.ptr<cv::Point2f>(y);
    const cv::Point2f* b = backward_at_end.ptr<cv::Point2f>(y);
    const cv::Point2f* m = map.ptr<cv::Point2f>(y);
    uchar* c = consistent.ptr<uchar>(y);
    for (int x = 0; x < forward.cols; ++x) {
      if (!(m[x].x >= 0.0f && m[x].y >= 0.0f && m[x].x <= forward.cols - 1 && m[x].y <= forward.rows - 1))
        continue;
      const cv::Point2f sum = f[x] + b[x];
      if (sum.dot(sum) < 0.01f * (f[x].dot(f[x]) + b[x].dot(b[x])) + 0.5f) c[x] = 255;
    }
  }
  return consistent;
}

cv::Mat EpipolarDistances(const PinholeCamera& camera, const SparseStructure& structure, int t, int s,
                          const cv::Mat& flow, const cv::Mat& consistent, double cap) {
  const SE3 T_s_t = structure.T_cam_world[s] * structure.T_cam_world[t].Inverse();
  const Eigen::Vector3d b = T_s_t.translation();
  Eigen::Matrix3d b_cross;
  b_cross << 0.0, -b.z(), b.y(), b.z(), 0.0, -b.x(), -b.y(), b.x(), 0.0;
  const Eigen::Matrix3d K_inv = camera.K().inverse();
  const Eigen::Matrix3d fundamental = K_inv.transpose() * b_cross * T_s_t.rotation() * K_inv;
  cv::Mat distance(flow.rows, flow.cols, CV_32FC1, cv::Scalar(0.0f));
  for (int y = 0; y < flow.rows; ++y) {
    const cv::Point2f* f = flow.ptr<cv::Point2f>(y);
    float* d = distance.ptr<float>(y);
    const uchar* c = consistent.ptr<uchar>(y);
    for (int x = 0; x < flow.cols; ++x) {
      if (c[x] == 0) continue;
      const double u = x + f[x].x, v = y + f[x].y;
      if (!std::isfinite(u) || !std::isfinite(v) || !camera.InImage(u, v)) continue;
      const Eigen::Vector3d line = fundamental * Eigen::Vector3d(x, y, 1.0);
      const double norm = std::hypot(line.x(), line.y());
      if (!(norm > 0.0)) continue;
      d[x] = static_cast<float>(std::min(cap, std::abs(line.dot(Eigen::Vector3d(u, v, 1.0))) / norm));
    }
  }
  return distance;
}

// InitializerOptions::flow_fixation_test: the epipolar distances of a dense
// flow of the pairs t -> t+k (flow_test_min_gap <= k <= flow_test_max_gap)
// under the structure without the turn against those under the turn,
// compared as CompareDataCosts compares costs.
DataCostComparison CompareFlowEpipolarDistances(const std::vector<cv::Mat>& gray, const PinholeCamera& camera,
                                                const InitializerOptions& options,
                                                const SparseStructure& still, const SparseStructure& turned) {
  std::vector<cv::Mat> before, after;
  cv::Ptr<cv::DISOpticalFlow> dis = cv::DISOpticalFlow::create(cv::DISOpticalFlow::PRESET_MEDIUM);
  std::vector<cv::Mat> gray8(gray.size());
  for (size_t t = 0; t < gray.size(); ++t) gray[t].convertTo(gray8[t], CV_8UC1, 255.0);
  cv::Mat flow, back;
  const int num_frames = static_cast<int>(gray.size());
  for (int step = options.flow_test_min_gap; step <= options.flow_test_max_gap && step < num_frames; ++step) {
    for (int t = 0; t + step < num_frames; ++t) {
      dis->calc(gray8[t], gray8[t + step], flow);
      dis->calc(gray8[t + step], gray8[t], back);
      const cv::Mat consistent = ForwardBackwardConsistent(flow, back);
      before.push_back(
          EpipolarDistances(camera, still, t, t + step, flow, consistent, options.pnp_threshold_px));
      after.push_back(
          EpipolarDistances(camera, turned, t, t + step, flow, consistent, options.pnp_threshold_px));
    }
  }
  return CompareDataCosts(before, after, options.flow_test_tile_px);
}

// The flow test's bound: Student's t quantile with tiles - 1 degrees of
// freedom at the one-sided level of the normal quantile z.
double FlowTestBound(double z, int tiles) {
  if (tiles < 2) return std::numeric_limits<double>::infinity();
  const double level = boost::math::cdf(boost::math::normal(), z);
  return boost::math::quantile(boost::math::students_t(tiles - 1.0), level);
}

// The flow's decision between the structure without the turn (`still`) and
// with it (`turned`): true when the turn lowers the flow's epipolar
// distances by more than FlowTestBound(z). One summary line named `name`,
// ending in "turn kept" or `otherwise`.
bool FlowFavoursTurn(const std::vector<cv::Mat>& gray, const PinholeCamera& camera,
                     const InitializerOptions& options, const SparseStructure& still,
                     const SparseStructure& turned, double z, const std::string& name,
                     const std::string& otherwise, std::ostringstream* summary) {
  const double test_ms = NowMs();
  const DataCostComparison gain = CompareFlowEpipolarDistances(gray, camera, options, still, turned);
  const double bound = FlowTestBound(z, gain.blocks);
  const bool turns = gain.z > bound;
  const int num_frames = static_cast<int>(gray.size());
  *summary << name
           << Format(": the turn lowers the flow's epipolar distances by %.3g %% (%.4g px; "
                     "%.2f standard errors over %.0f tiles, bound %.2f; ",
                     100.0 * gain.relative, gain.mean, gain.z, gain.blocks, bound)
           << Format("%.0f pairs of gaps %.0f-%.0f; %.1f ms): ", gain.maps, options.flow_test_min_gap,
                     std::min(options.flow_test_max_gap, num_frames - 1), NowMs() - test_ms)
           << (turns ? std::string("turn kept") : otherwise) << "\n";
  return turns;
}

// Poses at shutter close and dense depths (stage 4) of a bundle-adjusted
// structure; the data cost of the depths' solution per pixel in `data_cost`.
InitialStructure DenseStructure(const std::vector<cv::Mat>& images, const PinholeCamera& camera_lr,
                                const std::vector<FrameRecord>& frames, const std::vector<Track>& tracks,
                                const InitializerOptions& options, int threads, double readout_time,
                                SparseStructure* structure, std::ostringstream* summary,
                                std::vector<cv::Mat>* data_cost) {
  InitialStructure result;
  std::vector<SE3> T_world_mid;
  MoveToShutterClose(frames, structure, &result.T_world_cam, &T_world_mid, summary);
  const DepthRanges ranges = ComputeDepthRanges(tracks, *structure, result.T_world_cam, options);
  result.depth_lr = DepthStage(images, camera_lr, frames, result.T_world_cam, T_world_mid, ranges, options,
                               threads, readout_time, summary, data_cost);
  return result;
}

// The sparse part of InitializeStructure: the tracks, the two-view start,
// PnP and the bundle adjustment, the turn checks, the rolling-shutter
// correction and the pose prior. `rejected_turn` keeps the structure with
// the turn that the dense turn test (InitializerOptions::dense_fixation_test)
// is to judge, when it has one to judge.
struct SparseInitialisation {
  TrackedWindow window;
  SparseStructure structure;
  std::optional<SparseStructure> rejected_turn;
  // With a rolling shutter: the tracks as observed, before the rows' delays
  // were corrected in window.tracking (the same points); empty otherwise.
  std::vector<Track> observed_tracks;
};

SparseInitialisation InitializeSparse(const std::vector<cv::Mat>& images_lr, const PinholeCamera& camera_lr,
                                      const std::vector<FrameRecord>& frames,
                                      const InitializerOptions& options, double readout_time,
                                      const std::vector<std::optional<SE3>>& T_prior_cam,
                                      std::ostringstream* summary) {
  SparseInitialisation sparse;
  sparse.window = TrackWindow(images_lr, camera_lr, frames, options, summary);
  TrackedWindow& window = sparse.window;
  std::vector<Track>& tracks = window.tracking.tracks;
  const int num_frames = static_cast<int>(images_lr.size());
  const int threads = window.threads;
  std::optional<SparseStructure>& rejected_turn = sparse.rejected_turn;
  std::optional<SparseStructure> kept_turn_still;
  SparseStructure& structure = sparse.structure;
  // With a rolling shutter the tracks are tested after the rows' delays are
  // corrected: before, a global-shutter adjustment leaves the delays in the
  // errors of the tracks that carry them.
  const bool has_prior = HasAnyPriorPose(T_prior_cam);
  structure = SparseStage(camera_lr, options, threads, num_frames, /*track_consistency=*/readout_time == 0.0,
                          /*flow_check_follows=*/options.flow_turn_check && !has_prior, &tracks, summary,
                          &rejected_turn, &kept_turn_still);
  if (!(options.dense_fixation_test || options.flow_fixation_test) || readout_time > 0.0 || has_prior) {
    rejected_turn.reset();
  }
  if (kept_turn_still && options.flow_turn_check && !has_prior) {
    const bool keep_turn =
        FlowFavoursTurn(window.gray, camera_lr, options, *kept_turn_still, structure,
                        options.flow_turn_check_z, "flow turn check", "turn dropped", summary);
    if (!keep_turn) structure = std::move(*kept_turn_still);
  }
  if (rejected_turn && options.flow_fixation_test) {
    const bool keep_turn = FlowFavoursTurn(window.gray, camera_lr, options, structure, *rejected_turn,
                                           options.dense_test_z, "flow turn test", "no turn", summary);
    if (keep_turn) structure = std::move(*rejected_turn);
    rejected_turn.reset();
  }
  if (readout_time > 0.0) {
    sparse.observed_tracks = tracks;
    const double rms = CorrectRollingShutter(camera_lr, options, threads, frames, readout_time, &tracks,
                                             &structure, summary);
    int observations = 0;
    LeaveOutInconsistentTracks(camera_lr, options, threads, tracks, rms, &structure, &observations, summary);
  }
  AdjustToPosePrior(camera_lr, options, threads, frames, T_prior_cam, tracks, &structure, summary);
  return sparse;
}

// The tracks of the points `structure` keeps as inliers, as given.
std::vector<FeatureTrack> KeptTracks(const std::vector<Track>& tracks, const SparseStructure& structure) {
  std::vector<FeatureTrack> kept;
  for (const Track& track : tracks) {
    if (track.point_id < 0 || !structure.point_inlier[track.point_id]) continue;
    FeatureTrack out;
    out.first_frame = track.first_frame;
    for (const cv::Point2f& p : track.points) out.points.emplace_back(p.x, p.y);
    kept.push_back(std::move(out));
  }
  return kept;
}

InitialStructure InitializeStructureUnguarded(const std::vector<cv::Mat>& images_lr,
                                              const PinholeCamera& camera_lr,
                                              const std::vector<FrameRecord>& frames,
                                              const InitializerOptions& options, double readout_time,
                                              const std::vector<std::optional<SE3>>& T_prior_cam) {
  const double start_ms = NowMs();
  std::ostringstream summary;
  SparseInitialisation sparse =
      InitializeSparse(images_lr, camera_lr, frames, options, readout_time, T_prior_cam, &summary);
  const TrackingResult& tracking = sparse.window.tracking;
  const std::vector<cv::Mat>& images = sparse.window.images;
  const int threads = sparse.window.threads;
  SparseStructure& structure = sparse.structure;
  std::optional<SparseStructure>& rejected_turn = sparse.rejected_turn;
  std::vector<cv::Mat> data_cost;
  bool kept_turn = false;
  InitialStructure result = DenseStructure(images, camera_lr, frames, tracking.tracks, options, threads,
                                           readout_time, &structure, &summary,
                                           rejected_turn ? &data_cost : nullptr);
  if (rejected_turn) {
    std::ostringstream turn_summary;
    std::vector<cv::Mat> turn_cost;
    InitialStructure turned = DenseStructure(images, camera_lr, frames, tracking.tracks, options, threads,
                                             readout_time, &*rejected_turn, &turn_summary, &turn_cost);
    const DataCostComparison gain = CompareDataCosts(data_cost, turn_cost, options.dense_test_block_px);
    const bool keep_turn = gain.z > options.dense_test_z;
    summary << Format("dense turn test: the turn lowers the depths' data cost by %.3g %% (%.4g per pixel; "
                      "%.2f standard errors over %.0f blocks, bound %.2f): ",
                      100.0 * gain.relative, gain.mean, gain.z, gain.blocks, options.dense_test_z)
            << (keep_turn ? "turn kept\n" : "no turn\n");
    if (keep_turn) {
      summary << turn_summary.str();
      result = std::move(turned);
      kept_turn = true;
    }
  }
  result.tracks = KeptTracks(sparse.observed_tracks.empty() ? tracking.tracks : sparse.observed_tracks,
                             kept_turn ? *rejected_turn : structure);
  NormaliseGauge(&result, &summary);
  summary << Format("total: %.1f ms", NowMs() - start_ms);
  result.summary = summary.str();
  return result;
}

// InitializeTrajectory (initializer.h): the sparse part, its poses moved to
// t_c and scaled by the median depth of the inlier points, each seen from
// the first frame that tracks it.
InitialTrajectory InitializeTrajectoryUnguarded(const std::vector<cv::Mat>& images_lr,
                                                const PinholeCamera& camera_lr,
                                                const std::vector<FrameRecord>& frames,
                                                const InitializerOptions& options, double readout_time) {
  const double start_ms = NowMs();
  std::ostringstream summary;
  SparseInitialisation sparse =
      InitializeSparse(images_lr, camera_lr, frames, options, readout_time, {}, &summary);
  InitialTrajectory result;
  std::vector<SE3> T_world_mid;
  MoveToShutterClose(frames, &sparse.structure, &result.T_world_cam, &T_world_mid, &summary);
  std::vector<double> depths;
  for (const Track& track : sparse.window.tracking.tracks) {
    if (track.point_id < 0 || !sparse.structure.point_inlier[track.point_id]) continue;
    const Eigen::Vector3d point_cam =
        result.T_world_cam[track.first_frame].Inverse() * sparse.structure.points_world[track.point_id];
    if (point_cam.z() > 0.0 && std::isfinite(point_cam.z())) depths.push_back(point_cam.z());
  }
  if (depths.empty())
    throw InitializationError("initialisation: no triangulated point in front of the cameras");
  const double median = Median(depths);
  for (SE3& T : result.T_world_cam) T = SE3(T.rotation(), T.translation() / median);
  summary << Format("gauge: world = camera 0 at t_c, median point depth 1 (%.4g pair baselines)\n", median);
  summary << Format("total: %.1f ms", NowMs() - start_ms);
  result.summary = summary.str();
  return result;
}

// Observations of the points `inlier` selects: the count that the RMS of
// MeasureReprojectionCost's capped squares divides by.
int CountObservations(const std::vector<Track>& tracks, const std::vector<char>& inlier) {
  int count = 0;
  for (const Track& track : tracks) {
    if (track.point_id >= 0 && inlier[track.point_id]) count += static_cast<int>(track.points.size());
  }
  return count;
}

double MedianFrameInterval(const std::vector<FrameRecord>& frames) {
  std::vector<double> intervals;
  for (size_t t = 1; t < frames.size(); ++t) intervals.push_back(frames[t].stamp - frames[t - 1].stamp);
  return Median(intervals);
}

// EstimateReadoutTime's search (initializer.h) on the tracks and the
// global-shutter structure of the sparse stage.
ReadoutEstimate EstimateReadoutTimeUnguarded(const std::vector<cv::Mat>& images_lr,
                                             const PinholeCamera& camera_lr,
                                             const std::vector<FrameRecord>& frames,
                                             const InitializerOptions& options,
                                             const ReadoutSearchOptions& search) {
  const double start_ms = NowMs();
  std::ostringstream log;
  TrackedWindow window = TrackWindow(images_lr, camera_lr, frames, options, &log);
  const int num_frames = static_cast<int>(images_lr.size());
  std::optional<SparseStructure> rejected_turn, kept_turn_still;
  // The tracks untested: a global-shutter adjustment would take those that
  // carry the rows' delays for tracks that follow no point.
  const SparseStructure global = SparseStage(
      camera_lr, options, window.threads, num_frames, /*track_consistency=*/false,
      /*flow_check_follows=*/false, &window.tracking.tracks, &log, &rejected_turn, &kept_turn_still);
  const std::vector<char> inlier = global.point_inlier;
  const int observations = std::max(1, CountObservations(window.tracking.tracks, inlier));
  const double interval = MedianFrameInterval(frames);
  ReadoutEstimate estimate;
  const int steps = static_cast<int>(std::floor(search.max_fraction / search.fraction_step + 1e-9));
  for (int k = 0; k <= steps; ++k) {
    const double fraction = k * search.fraction_step;
    std::vector<Track> tracks = window.tracking.tracks;
    SparseStructure structure = global;
    if (k > 0) {
      std::ostringstream ignored;
      CorrectRollingShutter(camera_lr, options, window.threads, frames, fraction * interval, &tracks, &structure,
                            &ignored);
    }
    const ReprojectionCost cost =
        MeasureReprojectionCost(camera_lr, tracks, structure, inlier, options.pnp_threshold_px);
    estimate.cost.emplace_back(fraction, std::sqrt(cost.capped_squares / observations));
  }
  const auto best = std::min_element(estimate.cost.begin(), estimate.cost.end(),
                                     [](const auto& a, const auto& b) { return a.second < b.second; });
  const size_t k = static_cast<size_t>(best - estimate.cost.begin());
  const double fraction = RefinedGridMinimum(estimate.cost, k);
  // ReadoutEstimate::sharpness.
  const std::vector<std::pair<double, double>>& c = estimate.cost;
  const double at_minimum = std::max(c[k].second, 1e-12);
  if (k > 0 && k + 1 < c.size()) {
    estimate.sharpness = (c[k - 1].second + c[k + 1].second - 2.0 * c[k].second) / at_minimum;
  } else if (c.size() >= 2) {
    const size_t neighbour = k == 0 ? 1 : k - 1;
    estimate.sharpness = 2.0 * std::abs(c[neighbour].second - c[k].second) / at_minimum;
  }
  const double global_rms = estimate.cost.front().second;
  estimate.measured = k > 0 && best->second <= (1.0 - search.min_relative_gain) * global_rms;
  estimate.fraction = estimate.measured ? fraction : 0.0;
  estimate.seconds = estimate.fraction * interval;
  estimate.elapsed_seconds = (NowMs() - start_ms) / 1000.0;
  estimate.summary = Format("readout %.3f of the frame interval (%.4f s, ", estimate.fraction, estimate.seconds) +
                     (estimate.measured ? "measured" : "no rolling shutter measured") +
                     Format("): rms %.3f px against %.3f px with a global shutter over %.0f observations; %.1f ms",
                            best->second, global_rms, observations, estimate.elapsed_seconds * 1000.0);
  return estimate;
}

// The smallest half-size frame side the retry at half resolution
// (InitializerOptions::half_resolution_retry) runs on.
constexpr int kMinHalfResolutionSide = 48;

// The frames box-downsampled by 2 (DownsampleBox; an odd last row or column
// dropped, as PinholeCamera::Downscaled drops it).
std::vector<cv::Mat> HalfSizeFrames(const std::vector<cv::Mat>& images_lr) {
  std::vector<cv::Mat> half;
  for (const cv::Mat& image : images_lr) {
    half.push_back(DownsampleBox(image(cv::Rect(0, 0, image.cols / 2 * 2, image.rows / 2 * 2)), 2));
  }
  return half;
}

// A half-size depth map bilinearly up-sampled to `size` (the pixel centres of
// the scaling rule; a dropped odd row or column replicated).
cv::Mat DepthAtInputSize(const cv::Mat& half, const cv::Size& size) {
  cv::Mat up;
  cv::resize(half, up, cv::Size(half.cols * 2, half.rows * 2), 0.0, 0.0, cv::INTER_LINEAR);
  if (up.size() != size) {
    cv::copyMakeBorder(up.clone(), up, 0, size.height - up.rows, 0, size.width - up.cols,
                       cv::BORDER_REPLICATE);
  }
  return up;
}

// `attempt(images, camera)` at the input size, and with
// InitializerOptions::half_resolution_retry, after an InitializationError
// other than NoParallaxError (a rotation: EstimateRotationOnlyMotion's case),
// once more on the frames box-downsampled by 2 (HalfSizeFrames) and
// PinholeCamera::Downscaled(2); `to_input_size(result, why)` then brings the
// half-size result to the input size and says why in its summary. When both
// fail, the error names both reasons: a NoParallaxError when the half-size
// frames only turn, an InitializationError otherwise.
template <typename Attempt, typename ToInputSize>
auto WithHalfResolutionRetry(const std::vector<cv::Mat>& images_lr, const PinholeCamera& camera_lr,
                             const InitializerOptions& options, const Attempt& attempt,
                             const ToInputSize& to_input_size) {
  try {
    return attempt(images_lr, camera_lr);
  } catch (const NoParallaxError&) {
    throw;
  } catch (const InitializationError& failure) {
    const PinholeCamera half_camera = camera_lr.Downscaled(2);
    if (!options.half_resolution_retry || half_camera.width < kMinHalfResolutionSide ||
        half_camera.height < kMinHalfResolutionSide) {
      throw;
    }
    try {
      auto half = attempt(HalfSizeFrames(images_lr), half_camera);
      to_input_size(&half, Format("half resolution: %.0fx%.0f px (", half_camera.width, half_camera.height) +
                               failure.what() + " at the input size)");
      return half;
    } catch (const NoParallaxError& again) {
      // The half-size frames track, and only turn: a rotation, whose
      // orientations EstimateRotationOnlyMotion measures (at half size too).
      throw NoParallaxError(std::string(again.what()) +
                            " (at half resolution; at the input size: " + failure.what() + ")");
    } catch (const InitializationError& again) {
      throw InitializationError(std::string(failure.what()) + "; at half resolution: " + again.what());
    }
  }
}

}  // namespace

InitialStructure InitializeStructure(const std::vector<cv::Mat>& images_lr, const PinholeCamera& camera_lr,
                                     const std::vector<FrameRecord>& frames,
                                     const InitializerOptions& options, double readout_time,
                                     const std::vector<std::optional<SE3>>& T_prior_cam) {
  if (!std::isfinite(readout_time) || readout_time < 0.0) {
    throw InputError("initialisation: readout_time must be finite and >= 0");
  }
  if (!T_prior_cam.empty() && T_prior_cam.size() != frames.size()) {
    throw InputError("initialisation: " + std::to_string(T_prior_cam.size()) + " pose prior entries for " +
                     std::to_string(frames.size()) + " frames");
  }
  return WithOpenCvErrorsAsInitializationErrors("initialisation: degenerate geometry (OpenCV: ", [&] {
    return WithHalfResolutionRetry(
        images_lr, camera_lr, options,
        [&](const std::vector<cv::Mat>& images, const PinholeCamera& camera) {
          return InitializeStructureUnguarded(images, camera, frames, options, readout_time, T_prior_cam);
        },
        [&](InitialStructure* half, const std::string& why) {
          for (cv::Mat& depth : half->depth_lr)
            depth = DepthAtInputSize(depth, cv::Size(camera_lr.width, camera_lr.height));
          // Half-size pixel u is input pixel 2 u + 0.5 (PinholeCamera::Upscaled).
          for (FeatureTrack& track : half->tracks) {
            for (Eigen::Vector2d& point : track.points) point = 2.0 * point + Eigen::Vector2d(0.5, 0.5);
          }
          half->summary = why + "\n" + half->summary;
        });
  });
}

InitialTrajectory InitializeTrajectory(const std::vector<cv::Mat>& images_lr, const PinholeCamera& camera_lr,
                                       const std::vector<FrameRecord>& frames,
                                       const InitializerOptions& options, double readout_time) {
  if (!std::isfinite(readout_time) || readout_time < 0.0) {
    throw InputError("initialisation: readout_time must be finite and >= 0");
  }
  return WithOpenCvErrorsAsInitializationErrors("initialisation: degenerate geometry (OpenCV: ", [&] {
    return WithHalfResolutionRetry(
        images_lr, camera_lr, options,
        [&](const std::vector<cv::Mat>& images, const PinholeCamera& camera) {
          return InitializeTrajectoryUnguarded(images, camera, frames, options, readout_time);
        },
        [](InitialTrajectory* half, const std::string& why) { half->summary = why + "\n" + half->summary; });
  });
}

RotationOnlyMotion EstimateRotationOnlyMotion(const std::vector<cv::Mat>& images_lr,
                                              const PinholeCamera& camera_lr,
                                              const std::vector<FrameRecord>& frames,
                                              const InitializerOptions& options) {
  return WithOpenCvErrorsAsInitializationErrors("initialisation: rotation-only motion (OpenCV: ", [&] {
    return WithHalfResolutionRetry(
        images_lr, camera_lr, options,
        [&](const std::vector<cv::Mat>& images, const PinholeCamera& camera) {
          return EstimateRotationOnlyMotionUnguarded(images, camera, frames, options);
        },
        [](RotationOnlyMotion* half, const std::string& why) { half->summary = why + "\n" + half->summary; });
  });
}

void ReadoutSearchOptions::Check() const {
  CheckInRange("max_fraction", max_fraction, 0.05, 2.0);
  CheckInRange("fraction_step", fraction_step, 0.01, max_fraction);
  CheckInRange("min_relative_gain", min_relative_gain, 0.0, 0.5);
}

ReadoutEstimate EstimateReadoutTime(const std::vector<cv::Mat>& images_lr, const PinholeCamera& camera_lr,
                                    const std::vector<FrameRecord>& frames, const InitializerOptions& options,
                                    const ReadoutSearchOptions& search) {
  search.Check();
  return WithOpenCvErrorsAsInitializationErrors("readout estimation: degenerate geometry (OpenCV: ", [&] {
    return WithHalfResolutionRetry(
        images_lr, camera_lr, options,
        [&](const std::vector<cv::Mat>& images, const PinholeCamera& camera) {
          return EstimateReadoutTimeUnguarded(images, camera, frames, options, search);
        },
        [](ReadoutEstimate* half, const std::string& why) { half->summary = why + ": " + half->summary; });
  });
}

}  // namespace deblur_sr_mvs
