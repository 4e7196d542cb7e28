// Windows without parallax (docs/file_formats.md#no-parallax): the estimator
// and the stream restore the images of a pure rotation with depth at
// infinity, publish every frame with its orientation and NaN depth, and a
// later window with parallax continues the same trajectory.
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <Eigen/Geometry>

#include "../support/test_sequences.h"
#include "deblur_sr_mvs/core/estimation/estimator.h"
#include "deblur_sr_mvs/core/estimation/stream.h"
#include "deblur_sr_mvs/core/evaluation/metrics.h"
#include "deblur_sr_mvs/core/imaging/image_ops.h"

namespace deblur_sr_mvs {
namespace {

constexpr double kDegree = M_PI / 180.0;

const Sequence& RotationSequence() {
  static const Sequence sequence = SynthesizedSequence(
      "rotation_only", "Dolls", "--path rotate --frames 6 --subframes 100 --hr-width 240 --hr-height 180");
  return sequence;
}

// Angle (deg) between the estimated and the true orientation of frame t,
// both relative to frame `anchor`.
double RelativeRotationErrorDeg(const std::vector<SE3>& estimate, const std::vector<StampedPose>& truth,
                                size_t anchor, size_t t) {
  const Eigen::Matrix3d R_est = estimate[anchor].rotation().transpose() * estimate[t].rotation();
  const Eigen::Matrix3d R_true =
      truth[anchor].T_world_cam.rotation().transpose() * truth[t].T_world_cam.rotation();
  return Eigen::AngleAxisd(R_est.transpose() * R_true).angle() / kDegree;
}

bool AllNaN(const cv::Mat& depth) {
  for (int y = 0; y < depth.rows; ++y) {
    for (int x = 0; x < depth.cols; ++x) {
      if (!std::isnan(depth.at<float>(y, x))) return false;
    }
  }
  return true;
}

TEST(RotationOnly, EstimatorRestoresEveryFrameWithItsOrientation) {
  const Sequence& sequence = RotationSequence();
  ASSERT_TRUE(sequence.ground_truth.has_value());
  const EstimatorInput input = InputOf(sequence);
  const EstimatorResult result = Estimator(EstimatorOptions()).Run(input);
  ASSERT_EQ(result.latent.size(), input.images.size());
  EXPECT_FALSE(result.depth_observable);
  ASSERT_FALSE(result.notes.empty());
  EXPECT_EQ(result.notes.back(), kNoParallaxNote);

  std::vector<cv::Mat> bicubic;
  for (const cv::Mat& image : input.images) bicubic.push_back(UpsampleBicubic(image, 2));
  const double psnr_bicubic = MeanPsnr(bicubic, sequence.ground_truth->latent);
  const double psnr_restored = MeanPsnr(result.latent, sequence.ground_truth->latent);
  double worst_deg = 0.0;
  for (size_t t = 0; t < result.T_world_cam.size(); ++t) {
    EXPECT_TRUE(AllNaN(result.depth[t])) << "frame " << t;
    EXPECT_LT(result.T_world_cam[t].translation().norm(), 1e-12) << "frame " << t;
    worst_deg =
        std::max(worst_deg, RelativeRotationErrorDeg(result.T_world_cam, sequence.ground_truth->poses, 0, t));
  }
  std::printf("pure rotation: bicubic %.2f dB, restored %.2f dB; worst rotation error %.3f deg\n",
              psnr_bicubic, psnr_restored, worst_deg);
  EXPECT_GE(psnr_restored, psnr_bicubic + 4.0);
  EXPECT_LE(worst_deg, 0.2);
}

// A camera that first rotates about its centre, then translates: the first
// half of a `rotate` sequence followed by the second half of a `lateral` one
// (both paths pass through the same pose at the middle of the sequence).
TEST(RotationOnly, StreamPublishesEveryFrameAndContinuesIntoParallax) {
  const std::string flags = "--frames 8 --subframes 100 --hr-width 240 --hr-height 180";
  const Sequence rotate = SynthesizedSequence("rotate_half", "Dolls", "--path rotate " + flags);
  const Sequence lateral = SynthesizedSequence("lateral_half", "Dolls", "--path lateral " + flags);
  std::vector<cv::Mat> images;
  std::vector<FrameRecord> frames;
  std::vector<StampedPose> truth;
  for (int t = 0; t < 8; ++t) {
    const Sequence& source = t < 4 ? rotate : lateral;
    images.push_back(source.images[t]);
    frames.push_back(source.frames[t]);
    truth.push_back(source.ground_truth->poses[t]);
  }
  StreamOptions stream_options;
  stream_options.window_size = 4;
  stream_options.window_overlap = 2;
  const std::vector<StreamWindow> windows = StreamWindowsOf(images, frames, stream_options, 1);
  ASSERT_EQ(windows.size(), 3u);  // frames 0-3, 2-5, 4-7

  StreamEstimator stream(FastEstimatorOptions());
  std::vector<SE3> published;
  std::vector<bool> observable;
  for (size_t w = 0; w < windows.size(); ++w) {
    const WindowEstimate estimate = stream.Process(windows[w], rotate.calibration.camera);
    std::printf("window %zu: %s; depth %s\n", w, estimate.note.c_str(),
                estimate.result.depth_observable ? "observable" : "not observable");
    EXPECT_EQ(estimate.continued, w > 0) << estimate.note;
    EXPECT_EQ(ProblemWithEstimate(estimate.result, 20.0), "");
    for (size_t i = estimate.first_new; i < estimate.ids.size(); ++i) {
      published.push_back(estimate.result.T_world_cam[i]);
      observable.push_back(estimate.result.depth_observable);
    }
  }
  ASSERT_EQ(published.size(), 8u);   // every frame once
  EXPECT_FALSE(observable.front());  // frames 0-3 rotate only
  EXPECT_TRUE(observable.back());    // frames 6-7 come from a window with parallax
  double worst_deg = 0.0;
  for (size_t t = 1; t < published.size(); ++t) {
    const double error = RelativeRotationErrorDeg(published, truth, 0, t);
    std::printf("  frame %zu: orientation error %.3f deg\n", t, error);
    worst_deg = std::max(worst_deg, error);
  }
  std::printf("rotation then translation: worst orientation error %.3f deg over 8 frames\n", worst_deg);
  EXPECT_LE(worst_deg, 0.5);
}

}  // namespace
}  // namespace deblur_sr_mvs
