// The agreement mask of the multi-frame data pass (multi_frame_data.h): a
// neighbour's LR pixel counts where its prediction matches its observation
// within the threshold over a patch, is dropped around a disagreeing region
// (occlusion, mis-registration) and where it is not visible; bad options throw.
// The pass itself: test/core/estimation/noise_test.cc (Noise.MultiFrameDataPass*).
#include "deblur_sr_mvs/core/estimation/multi_frame_data.h"

#include <gtest/gtest.h>

#include "deblur_sr_mvs/core/common/errors.h"

namespace deblur_sr_mvs {
namespace {

cv::Mat NoisyImage(int channels, double sigma, int seed) {
  cv::Mat image(40, 50, CV_32FC(channels), cv::Scalar::all(0.5));
  cv::Mat noise(image.size(), image.type());
  cv::RNG rng(seed);
  rng.fill(noise, cv::RNG::NORMAL, 0.0, sigma);
  return image + noise;
}

TEST(MultiFrameAgreementMask, NoiseWithinTheThresholdAgrees) {
  for (int channels : {1, 3}) {
    const cv::Mat a = NoisyImage(channels, 2.0 / 255.0, 1), b = NoisyImage(channels, 2.0 / 255.0, 2);
    // The difference has RMS 2.8 gray levels; 2 x 2.8 = 5.7 as the threshold.
    const cv::Mat mask = MultiFrameAgreementMask(a, b, cv::Mat(), 5.7 / 255.0, 5);
    ASSERT_EQ(mask.type(), CV_8UC1);
    EXPECT_EQ(cv::countNonZero(mask), static_cast<int>(mask.total())) << channels << " channels";
  }
}

TEST(MultiFrameAgreementMask, DisagreeingRegionAndInvisiblePixelsAreDropped) {
  const cv::Mat a = NoisyImage(3, 2.0 / 255.0, 1);
  cv::Mat b = NoisyImage(3, 2.0 / 255.0, 2);
  b(cv::Rect(20, 10, 8, 8)) += cv::Scalar::all(0.2);  // another surface there
  cv::Mat visible(a.size(), CV_8UC1, cv::Scalar(255));
  visible.colRange(0, 5).setTo(0);
  const cv::Mat mask = MultiFrameAgreementMask(a, b, visible, 5.7 / 255.0, 5);
  EXPECT_EQ(cv::countNonZero(mask(cv::Rect(18, 8, 12, 12))), 0);  // the region and its patch rim
  EXPECT_EQ(cv::countNonZero(mask.colRange(0, 5)), 0);
  EXPECT_EQ(cv::countNonZero(mask(cv::Rect(35, 25, 15, 15))), 15 * 15);  // away from both
}

TEST(MultiFrameAgreementMask, RejectsMismatchedInputsAndBadOptions) {
  const cv::Mat a = NoisyImage(3, 0.01, 1), gray = NoisyImage(1, 0.01, 2);
  EXPECT_THROW(MultiFrameAgreementMask(a, gray, cv::Mat(), 0.1, 5), InputError);
  MultiFrameDataOptions options;
  EXPECT_NO_THROW(options.Check());
  options.patch_px = 4;
  EXPECT_THROW(options.Check(), InputError);
  options = MultiFrameDataOptions();
  options.relative_weight = -1.0;
  EXPECT_THROW(options.Check(), InputError);
  options = MultiFrameDataOptions();
  options.radius = 0;
  EXPECT_THROW(options.Check(), InputError);
}

}  // namespace
}  // namespace deblur_sr_mvs
