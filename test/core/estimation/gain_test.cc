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

// 8 Dolls frames at 240 x 180 with per-frame gains from [0.9, 1.1].
const GainSequence& Jittered() {
  static const GainSequence jittered = [] {
    const std::string folder = testing::TempDir() + "/dsm_gain_" + std::to_string(::getpid());
    const std::string command = std::string(DSM_TOOL_DIR) + "/synthesize_sequence --scene " + DSM_SOURCE_DIR +
                                "/data/middlebury/Dolls --output " + folder +
                                " --frames 8 --hr-width 240 --hr-height 180 --gain-jitter 0.1 --seed 3"
                                " > /dev/null";
    EXPECT_EQ(std::system(command.c_str()), 0) << command;
    GainSequence out;
    out.sequence = ReadSequence(folder, true);
    for (const YAML::Node& frame : YAML::LoadFile(folder + "/gt/synthesis.yaml")["frames"])
      out.gains.push_back(frame["gain"].as<double>());
    std::filesystem::remove_all(folder);
    return out;
  }();
  return jittered;
}

TEST(FrameGains, MatchTheSynthesizedGains) {
  const GainSequence& jittered = Jittered();
  ASSERT_EQ(jittered.gains.size(), 8u);
  const EstimatorInput input = InputOf(jittered.sequence);
  const std::vector<double> gains = EstimateFrameGains(input.images);
  ASSERT_EQ(gains.size(), jittered.gains.size());
  EXPECT_EQ(gains[0], 1.0);
  double worst = 0.0;
  for (size_t t = 0; t < gains.size(); ++t) {
    const double truth = jittered.gains[t] / jittered.gains[0];
    const double error = std::abs(gains[t] / truth - 1.0);
    std::cout << "frame " << t << ": true gain " << truth << ", estimated " << gains[t] << ", error "
              << 100.0 * error << " %\n";
    worst = std::max(worst, error);
  }
  // Measured: at most 0.54 % (frame 4; the pair ratios chain, so the error
  // grows along the window), against a jitter of +-10 % (up to 14 % between
  // frames 0 and 1). The bound leaves about twice the measured error for
  // other platforms' KLT and corner selection.
  EXPECT_LT(worst, 0.015);
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
  // Measured (estimate_sequence + evaluate_sequence, same sequence): depth
  // rel. error 0.0100 with the gains vs 0.0755 without (0.0100 on the same
  // sequence without jitter), PSNR 28.61 vs 27.34 dB. The bounds ask only
  // that compensation is not worse, and for depth that it removes at least
  // half of the damage (0.0100 is 7.5 times below 0.0755).
  EXPECT_LT(depth_on, 0.5 * depth_off);
  EXPECT_GE(psnr_on, psnr_off);
}

}  // namespace
}  // namespace deblur_sr_mvs
