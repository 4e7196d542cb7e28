// The re-sweep inside the joint iterations
// (DepthSweepOptions::before_last_structure_updates): the solver's own D_t
// is re-swept over the restored images before the last structure update,
// which continues from it. On a small Dolls sequence whose depth starts
// fattened at the object edges (the initialiser's failure the sweep
// corrects), the solver's depth ends closer to the truth than without the
// sweep, and the energy after every kept iteration still never increases.
#include <cstdio>
#include <string>
#include <vector>

#include <opencv2/imgproc.hpp>

#include <gtest/gtest.h>

#include "../support/test_sequences.h"
#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/estimation/estimator.h"
#include "deblur_sr_mvs/core/estimation/stream.h"

namespace deblur_sr_mvs {
namespace {

const Sequence& SmallSequence() {
  static const Sequence sequence =
      SynthesizedSequence("depth_sweep_iterations_seq", "Dolls", "--frames 5 --subframes 100");
  return sequence;
}

// The true depth with every near surface dilated by 4 px over the far one
// (a grey-scale erosion of depth: the nearest depth of a 9x9 window), the
// fattening of a window matcher.
std::vector<cv::Mat> FattenedDepths(const Sequence& sequence) {
  std::vector<cv::Mat> depths;
  for (const cv::Mat& truth : sequence.ground_truth->depth) {
    cv::Mat fattened;
    cv::erode(truth, fattened, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(9, 9)));
    depths.push_back(fattened);
  }
  return depths;
}

EstimatorResult RunWithSweepBefore(int before_last, const std::vector<cv::Mat>& depths) {
  const Sequence& sequence = SmallSequence();
  std::vector<SE3> poses;
  for (const StampedPose& p : sequence.ground_truth->poses) poses.push_back(p.T_world_cam);
  EstimatorOptions options;
  options.max_iterations = 1;
  options.depth_sweep.on_output = false;  // the solver's own depth is judged
  options.depth_sweep.before_last_structure_updates = before_last;
  return Estimator(options).RunFromStructure(InputOf(sequence), depths, poses);
}

TEST(DepthSweepIterations, SolverDepthStartsFromTheSweepAndEndsCloserToTheTruth) {
  const Sequence& sequence = SmallSequence();
  ASSERT_TRUE(sequence.ground_truth.has_value());
  const std::vector<cv::Mat> fattened = FattenedDepths(sequence);
  const EstimatorResult without = RunWithSweepBefore(0, fattened);
  const EstimatorResult with = RunWithSweepBefore(1, fattened);
  const double rel_start = MeanDepthRel(fattened, sequence.ground_truth->depth);
  const double rel_without = MeanDepthRel(without.depth, sequence.ground_truth->depth);
  const double rel_with = MeanDepthRel(with.depth, sequence.ground_truth->depth);
  std::printf("fattened depth rel %.4f: structure update %.4f, re-swept first %.4f\n", rel_start, rel_without,
              rel_with);
  EXPECT_LT(rel_with, rel_without);
  // The iteration was kept (not undone by a rise in energy) ...
  for (const std::string& note : with.notes) EXPECT_EQ(note.find("undone"), std::string::npos) << note;
  // ... and every kept image phase's energy is at most the one before.
  double previous = with.energies.front().total;
  for (const EnergyRecord& e : with.energies) {
    if (e.stage != "image") continue;
    EXPECT_LE(e.total, previous * (1.0 + 1e-9)) << "iteration " << e.iteration;
    previous = e.total;
  }
}

TEST(DepthSweepIterations, OffByDefaultAndInAStream) {
  EstimatorOptions options;
  EXPECT_EQ(options.depth_sweep.before_last_structure_updates, 0);
  options.depth_sweep.before_last_structure_updates = 2;
  EXPECT_NO_THROW(options.Check());
  const StreamEstimator stream(options);
  EXPECT_EQ(stream.options().depth_sweep.before_last_structure_updates, 0);
  options.depth_sweep.before_last_structure_updates = -1;
  EXPECT_THROW(options.Check(), InputError);
}

}  // namespace
}  // namespace deblur_sr_mvs
