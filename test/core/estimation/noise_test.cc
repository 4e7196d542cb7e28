// Sensor noise (issue 12): the joint estimate of a noisy sequence against
// bicubic up-sampling of its frames. scripts/benchmark_noise.sh measures the
// same on the four bundled scenes at sigma 0, 1, 2 and 4 (BENCHMARKS.md "Noise").
#include <cstdio>
#include <vector>

#include <gtest/gtest.h>

#include "../support/test_sequences.h"
#include "deblur_sr_mvs/core/estimation/estimator.h"
#include "deblur_sr_mvs/core/imaging/image_ops.h"

namespace deblur_sr_mvs {
namespace {

// Gaussian noise of sigma 2 gray levels on the LR frames (a well-lit 8-bit
// sensor; the reference level).
TEST(Noise, RestoredBeatsBicubicByFiveDecibelsAtSigmaTwo) {
  const Sequence sequence = SynthesizedSequence(
      "noise_seq", "Dolls", "--frames 5 --subframes 100 --hr-width 240 --hr-height 180 --noise 2 --seed 1");
  ASSERT_TRUE(sequence.ground_truth.has_value());
  const EstimatorInput input = InputOf(sequence);
  EstimatorOptions options;
  options.max_iterations = 1;
  const EstimatorResult result = Estimator(options).Run(input);
  std::vector<cv::Mat> bicubic;
  for (const cv::Mat& image : input.images) bicubic.push_back(UpsampleBicubic(image, 2));
  const double psnr_bicubic = MeanPsnr(bicubic, sequence.ground_truth->latent);
  const double psnr_restored = MeanPsnr(result.latent, sequence.ground_truth->latent);
  std::printf("sigma 2: PSNR bicubic %.2f dB, restored %.2f dB\n", psnr_bicubic, psnr_restored);
  // The target for sigma 2 (5 dB over bicubic on the bundled
  // scenes). Bicubic barely feels the noise (its error is the blur, ~25 gray
  // levels RMS here, against 2 of noise); the restored image must keep most
  // of its 9 dB gain of the noise-free sequence.
  EXPECT_GT(psnr_restored, psnr_bicubic + 5.0);
}

}  // namespace
}  // namespace deblur_sr_mvs
