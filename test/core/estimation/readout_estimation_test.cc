// The rolling shutter's readout time measured from the tracks
// (EstimateReadoutTime, `--readout-time auto`; docs/file_formats.md#rolling-shutter):
// hand-held Dolls sequences read out over 0.5 and 0.8 of the frame interval,
// and the same path with a global shutter.
#include <cstdio>
#include <string>

#include <gtest/gtest.h>

#include "../support/test_sequences.h"
#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/estimation/initializer.h"

namespace deblur_sr_mvs {
namespace {

constexpr char kPath[] = "--path handheld --frames 6 --hr-width 240 --hr-height 180 --seed 3";

ReadoutEstimate Measure(const std::string& tag, double readout_ratio) {
  const Sequence sequence =
      SynthesizedSequence(tag, "Dolls", std::string(kPath) + " --readout-ratio " + std::to_string(readout_ratio));
  const EstimatorInput input = InputOf(sequence);
  const ReadoutEstimate estimate =
      EstimateReadoutTime(input.images, input.camera, input.frames, InitializerOptions(), ReadoutSearchOptions());
  std::printf("readout %.1f: %s; sharpness %.4f\n  rms by fraction:", readout_ratio, estimate.summary.c_str(),
              estimate.sharpness);
  for (const auto& point : estimate.cost) std::printf(" %.1f:%.4f", point.first, point.second);
  std::printf("\n");
  return estimate;
}

// Within a tenth of the frame interval of the truth (measured here: 0.577
// for 0.5, 0.806 for 0.8; the tracks' own minimum, not the grid's spacing:
// a 0.025 grid puts it at 0.58 for 0.5), and in seconds: the fraction times
// the frame interval (30 fps).
TEST(ReadoutEstimation, MeasuresTheReadoutOfAHandHeldRollingShutter) {
  for (const double ratio : {0.5, 0.8}) {
    const ReadoutEstimate estimate = Measure("readout_" + std::to_string(ratio), ratio);
    EXPECT_TRUE(estimate.measured) << ratio;
    EXPECT_NEAR(estimate.fraction, ratio, 0.1);
    EXPECT_NEAR(estimate.seconds, estimate.fraction / 30.0, 1e-6);
    ASSERT_EQ(estimate.cost.size(), 11u);
    EXPECT_LT(estimate.cost[static_cast<size_t>(ratio * 10.0 + 0.5)].second, estimate.cost.front().second);
  }
}

// A global shutter: no candidate beats readout 0.
TEST(ReadoutEstimation, AGlobalShutterMeasuresNone) {
  const ReadoutEstimate estimate = Measure("readout_global", 0.0);
  EXPECT_FALSE(estimate.measured);
  EXPECT_EQ(estimate.fraction, 0.0);
  EXPECT_EQ(estimate.seconds, 0.0);
}

TEST(ReadoutEstimation, BadSearchOptionsAreRejected) {
  ReadoutSearchOptions options;
  options.fraction_step = 0.0;
  EXPECT_THROW(options.Check(), InputError);
  options = ReadoutSearchOptions();
  options.max_fraction = -1.0;
  EXPECT_THROW(options.Check(), InputError);
  options = ReadoutSearchOptions();
  options.min_relative_gain = 0.9;
  EXPECT_THROW(options.Check(), InputError);
  EXPECT_NO_THROW(ReadoutSearchOptions().Check());
}

}  // namespace
}  // namespace deblur_sr_mvs
