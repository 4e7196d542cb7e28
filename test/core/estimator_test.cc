// End-to-end properties of the estimator on a small synthesized sequence.
#include "deblur_sr_mvs/core/estimator.h"

#include <cstdlib>
#include <string>

#include <gtest/gtest.h>

#include "deblur_sr_mvs/core/image_ops.h"
#include "deblur_sr_mvs/core/metrics.h"
#include "deblur_sr_mvs/core/sequence_io.h"

namespace deblur_sr_mvs {
namespace {

// Synthesizes (once per test binary) a short Dolls sequence with ground truth.
const Sequence& SmallSequence() {
  static const Sequence sequence = [] {
    const std::string folder = testing::TempDir() + "/dsm_estimator_seq";
    const std::string command = std::string(DSM_TOOL_DIR) + "/synthesize_sequence --scene " +
                                DSM_SOURCE_DIR + "/data/middlebury/Dolls --output " + folder +
                                " --frames 5 --subframes 100 > /dev/null";
    EXPECT_EQ(std::system(command.c_str()), 0);
    return ReadSequence(folder, true);
  }();
  return sequence;
}

EstimatorInput InputOf(const Sequence& sequence) {
  EstimatorInput input;
  input.camera = sequence.calibration.camera;
  input.frames = sequence.frames;
  for (const cv::Mat& image : sequence.images) input.images.push_back(ToFloat01(image));
  return input;
}

double MeanPsnr(const std::vector<cv::Mat>& estimates01, const std::vector<cv::Mat>& truth8) {
  double sum = 0.0;
  for (size_t t = 0; t < estimates01.size(); ++t) {
    sum += Psnr(ToImage8(estimates01[t]), truth8[t], 255.0);
  }
  return sum / estimates01.size();
}

TEST(Estimator, ImageUpdateWithTrueStructureBeatsBicubic) {
  const Sequence& sequence = SmallSequence();
  ASSERT_TRUE(sequence.ground_truth.has_value());
  const EstimatorInput input = InputOf(sequence);
  std::vector<SE3> poses;
  for (const StampedPose& p : sequence.ground_truth->poses) poses.push_back(p.T_world_cam);
  EstimatorOptions options;
  options.update_structure = false;
  options.max_iterations = 1;
  Estimator estimator(options);
  const EstimatorResult result =
      estimator.RunFromStructure(input, sequence.ground_truth->depth, poses);
  std::vector<cv::Mat> bicubic;
  for (const cv::Mat& image : input.images) bicubic.push_back(UpsampleBicubic(image, 2));
  const double psnr_bicubic = MeanPsnr(bicubic, sequence.ground_truth->latent);
  const double psnr_restored = MeanPsnr(result.latent, sequence.ground_truth->latent);
  std::printf("true structure: bicubic %.2f dB, restored %.2f dB\n", psnr_bicubic, psnr_restored);
  EXPECT_GT(psnr_restored, psnr_bicubic + 3.0);
  // The image update may only lower the energy.
  ASSERT_GE(result.energies.size(), 2u);
  EXPECT_LT(result.energies.back().total, result.energies.front().total);
}

}  // namespace
}  // namespace deblur_sr_mvs
