// Auto-gain robustness (issue 12): the per-frame gains of
// EstimateFrameGains against the synthesizer's, and the estimator with gain
// compensation against without, on Dolls with --gain-jitter 0.1.
#include <unistd.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <string>
#include <vector>

#include <yaml-cpp/yaml.h>

#include <gtest/gtest.h>

#include "../support/test_sequences.h"
#include "deblur_sr_mvs/core/estimation/estimator.h"
#include "deblur_sr_mvs/core/estimation/photometric.h"
#include "deblur_sr_mvs/core/evaluation/metrics.h"

namespace deblur_sr_mvs {
namespace {

struct GainSequence {
  Sequence sequence;
  std::vector<double> gains;  // the synthesizer's (gt/synthesis.yaml)
};

// 8 Dolls frames at 240 x 180 along `path`, with per-frame gains from
// [1 - jitter, 1 + jitter] (seed 3: the same path and blur with any jitter).
GainSequence Synthesize(const std::string& path, double jitter) {
  const std::string folder = testing::TempDir() + "/dsm_gain_" + std::to_string(::getpid());
  const std::string command = std::string(DSM_TOOL_DIR) + "/synthesize_sequence --scene " + DSM_SOURCE_DIR +
                              "/data/middlebury/Dolls --output " + folder +
                              " --frames 8 --hr-width 240 --hr-height 180 --seed 3 --path " + path +
                              " --gain-jitter " + std::to_string(jitter) + " > /dev/null";
  EXPECT_EQ(std::system(command.c_str()), 0) << command;
  GainSequence out;
  out.sequence = ReadSequence(folder, true);
  for (const YAML::Node& frame : YAML::LoadFile(folder + "/gt/synthesis.yaml")["frames"])
    out.gains.push_back(frame["gain"].as<double>());
  std::filesystem::remove_all(folder);
  return out;
}

const GainSequence& Jittered() {
  static const GainSequence jittered = Synthesize("lateral", 0.1);
  return jittered;
}

// The largest |estimated / true - 1| over the frames; `truth` relative to frame 0.
double WorstGainError(const std::vector<double>& estimated, const std::vector<double>& truth) {
  EXPECT_EQ(estimated.size(), truth.size());
  EXPECT_EQ(estimated[0], 1.0);
  double worst = 0.0;
  for (size_t t = 0; t < estimated.size() && t < truth.size(); ++t) {
    const double error = std::abs(estimated[t] / (truth[t] / truth[0]) - 1.0);
    std::cout << "frame " << t << ": true gain " << truth[t] / truth[0] << ", estimated " << estimated[t]
              << ", error " << 100.0 * error << " %\n";
    worst = std::max(worst, error);
  }
  return worst;
}

// The rotate path has no parallax, and its renders all come from one of the
// scene's two photographs: the frames differ by the jitter alone.
TEST(FrameGains, MatchTheSynthesizedGainsWithoutParallax) {
  for (const double jitter : {0.0, 0.1}) {
    const GainSequence rotating = Synthesize("rotate", jitter);
    ASSERT_EQ(rotating.gains.size(), 8u);
    const double worst =
        WorstGainError(EstimateFrameGains(InputOf(rotating.sequence).images), rotating.gains);
    // Measured: 0.06 % (no jitter) and 0.02 % (jitter 0.1); 1.1 % with
    // the box means at the rounded track. 0.5 % is a quarter of what makes
    // the estimator measurably worse (2 %: 1.3 gray levels at mid-gray,
    // above the L1 residuals of a converged window) and covers other
    // platforms' KLT.
    EXPECT_LT(worst, 0.005) << "jitter " << jitter;
  }
}

// Along the lateral path the synthesized scene itself changes brightness
// between frames: the renderer switches from view1 to view5 of the
// Middlebury pair (photographs that differ by about 1 % in exposure and
// shading) where the camera passes the middle of the baseline, between
// frames 3 and 4 here, and parallax uncovers other surfaces. The estimate
// follows that change; the jitter must come out on top of it unchanged.
TEST(FrameGains, RecoverTheJitterOnTopOfTheSceneBrightness) {
  const GainSequence& jittered = Jittered();
  const GainSequence steady = Synthesize("lateral", 0.0);
  const std::vector<double> with_jitter = EstimateFrameGains(InputOf(jittered.sequence).images);
  const std::vector<double> without = EstimateFrameGains(InputOf(steady.sequence).images);
  ASSERT_EQ(with_jitter.size(), without.size());
  std::vector<double> jitter_only;
  for (size_t t = 0; t < with_jitter.size(); ++t) jitter_only.push_back(with_jitter[t] / without[t]);
  // Measured: 0.02 %, against a jitter of +-10 % (up to 14 % between
  // frames 0 and 1); bound as above.
  EXPECT_LT(WorstGainError(jitter_only, jittered.gains), 0.005);
  // The scene's own change: at most 2 % over the 8 frames (measured 1.5 %,
  // 0.9 % of it at the view switch); more would be an estimator drift.
  for (size_t t = 0; t < without.size(); ++t) EXPECT_NEAR(without[t], 1.0, 0.02) << "frame " << t;
}

TEST(FrameGains, OneForIdenticalFrames) {
  const EstimatorInput input = InputOf(Jittered().sequence);
  const std::vector<double> gains = EstimateFrameGains({input.images[0], input.images[0] * 1.0});
  EXPECT_NEAR(gains[1], 1.0, 1e-6);
}

// The whole estimator on the jittered frames, with and without the gains.
TEST(FrameGains, CompensationKeepsDepthAndImagesOfTheJitteredSequence) {
  const GainSequence& jittered = Jittered();
  const EstimatorInput input = InputOf(jittered.sequence);
  const SequenceGroundTruth& gt = *jittered.sequence.ground_truth;
  EstimatorOptions options;
  options.gain_compensation = true;
  const EstimatorResult on = Estimator(options).Run(input);
  options.gain_compensation = false;
  const EstimatorResult off = Estimator(options).Run(input);
  ASSERT_EQ(on.frame_gains.size(), input.images.size());
  EXPECT_TRUE(off.frame_gains.empty());
  const double depth_on = MeanDepthRel(on.depth, gt.depth), depth_off = MeanDepthRel(off.depth, gt.depth);
  const double psnr_on = MeanPsnr(on.latent, gt.latent), psnr_off = MeanPsnr(off.latent, gt.latent);
  std::cout << "depth rel. error: " << depth_on << " with the gains, " << depth_off << " without\n"
            << "restored PSNR: " << psnr_on << " dB with the gains, " << psnr_off << " dB without\n";
  // Measured: depth rel. error 0.0099 with the gains vs 0.0752 without
  // (0.0098 on the same sequence without jitter, with the gains), PSNR 28.60
  // vs 27.34 dB. The bounds ask only that compensation is not worse, and for
  // depth that it removes at least half of the damage (0.0099 is 7.6 times
  // below 0.0752).
  EXPECT_LT(depth_on, 0.5 * depth_off);
  EXPECT_GE(psnr_on, psnr_off);
}

}  // namespace
}  // namespace deblur_sr_mvs
