// Rolling shutter (issue 12, docs/file_formats.md#rolling-shutter): a
// hand-held Dolls sequence read out over 0.8 of the frame interval, estimated
// with the rolling-shutter model (sensor.yaml's readout time) and with a
// global-shutter model (readout 0), against the same path rendered with a
// global shutter.
#include <cstdio>
#include <string>

#include <gtest/gtest.h>

#include "../support/test_sequences.h"
#include "deblur_sr_mvs/core/estimation/estimator.h"
#include "deblur_sr_mvs/core/estimation/initializer.h"

namespace deblur_sr_mvs {
namespace {

constexpr char kPath[] = "--path handheld --frames 6 --hr-width 240 --hr-height 180 --seed 3";

struct Outcome {
  double psnr = 0.0;
  double depth_rel = 0.0;
};

// Also prints each frame's depth rel. error (where along the window the
// rolling shutter costs depth).
Outcome Estimate(const Sequence& sequence, double readout_time, const char* name) {
  EstimatorInput input = InputOf(sequence);
  input.readout_time = readout_time;
  // Default options (gain compensation on). Before the initialisation's
  // rolling-shutter correction followed the rows' quadratic path
  // (RowPose) this criterion was held at compensation off: 1.190 there,
  // 1.204 with it on (BENCHMARKS.md "Readout time measured from the tracks").
  const EstimatorOptions options;
  const EstimatorResult result = Estimator(options).Run(input);
  std::printf("%s, depth rel. per frame:", name);
  for (size_t t = 0; t < result.depth.size(); ++t) {
    std::printf(" %.4f", MeanDepthRel({result.depth[t]}, {sequence.ground_truth->depth[t]}));
  }
  std::printf("\n");
  return Outcome{MeanPsnr(result.latent, sequence.ground_truth->latent),
                 MeanDepthRel(result.depth, sequence.ground_truth->depth)};
}

// Also with the readout time measured from the tracks (EstimateReadoutTime,
// `--readout-time auto`) instead of sensor.yaml's: it must gain what the issue
// asks of the model, >= 2 dB over readout 0.
TEST(RollingShutter, ModelRestoresAndKeepsDepthNearTheGlobalShutter) {
  const Sequence rolling = SynthesizedSequence("rs_rolling", "Dolls", std::string(kPath) + " --readout-ratio 0.8");
  const Sequence global = SynthesizedSequence("rs_global", "Dolls", kPath);
  ASSERT_GT(rolling.readout_time, 0.0);
  const Outcome modelled = Estimate(rolling, rolling.readout_time, "rolling-shutter model");
  const Outcome ignored = Estimate(rolling, 0.0, "readout 0");
  const Outcome reference = Estimate(global, 0.0, "global-shutter sequence");
  const EstimatorInput input = InputOf(rolling);
  const ReadoutEstimate readout =
      EstimateReadoutTime(input.images, input.camera, input.frames, InitializerOptions(), ReadoutSearchOptions());
  const Outcome measured = Estimate(rolling, readout.seconds, "measured readout");
  std::printf("measured readout: %s; %.2f dB / depth %.4f\n", readout.summary.c_str(), measured.psnr,
              measured.depth_rel);
  std::printf("rolling shutter 0.8: model %.2f dB / depth %.4f; readout 0: %.2f dB / %.4f; global-shutter "
              "sequence: %.2f dB / %.4f\n",
              modelled.psnr, modelled.depth_rel, ignored.psnr, ignored.depth_rel, reference.psnr,
              reference.depth_rel);
  // The targets: >= 2 dB over the same run with readout 0, and the
  // depth rel. error within 20 % of the global-shutter sequence's.
  EXPECT_GE(modelled.psnr, ignored.psnr + 2.0);
  EXPECT_LE(modelled.depth_rel, 1.2 * reference.depth_rel);
  EXPECT_GE(measured.psnr, ignored.psnr + 2.0);
}

}  // namespace
}  // namespace deblur_sr_mvs
