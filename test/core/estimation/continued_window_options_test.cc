// EstimatorOptions::continued_*: a continued stream window's own budget of
// joint-step reweightings and CG steps, pose Gauss-Newton steps, iterations
// of Algorithm 1 and re-centred depth passes. Each applies to continued
// windows only (the first window keeps the general options), and a knob set
// to the value it replaces changes nothing bit for bit. And
// recentred_passes_on_held_frames, which only a continued window's held
// frames feel.
#include <cstring>
#include <vector>

#include <gtest/gtest.h>

#include "../support/same_bits.h"
#include "../support/test_sequences.h"
#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/estimation/estimator.h"
#include "deblur_sr_mvs/core/estimation/stream.h"

namespace deblur_sr_mvs {
namespace {

bool SameResult(const EstimatorResult& a, const EstimatorResult& b) {
  if (a.latent.size() != b.latent.size() || a.energies.size() != b.energies.size()) return false;
  for (size_t t = 0; t < a.latent.size(); ++t) {
    if (!SameBits(a.latent[t], b.latent[t]) || !SameBits(a.depth[t], b.depth[t])) return false;
    if (a.T_world_cam[t].rotation() != b.T_world_cam[t].rotation() ||
        a.T_world_cam[t].translation() != b.T_world_cam[t].translation()) {
      return false;
    }
  }
  for (size_t i = 0; i < a.energies.size(); ++i) {
    if (a.energies[i].total != b.energies[i].total) return false;
  }
  return true;
}

// Windows of 4 sharing 2 on 6 Dolls frames (frames 0-3, then 2-5), two
// iterations, one thread: the first and the continued window's estimates.
std::vector<WindowEstimate> RunStream(const EstimatorOptions& options) {
  static const Sequence sequence = SynthesizedSequence("continued_window_options", "Dolls",
                                                       "--frames 6 --subframes 60 --hr-width 192 --hr-height 144");
  StreamOptions stream_options;
  stream_options.window_size = 4;
  stream_options.window_overlap = 2;
  const std::vector<StreamWindow> windows = StreamWindowsOf(sequence.images, sequence.frames, stream_options, 0);
  EXPECT_EQ(windows.size(), 2u);
  StreamEstimator stream(options);
  std::vector<WindowEstimate> estimates;
  for (const StreamWindow& window : windows) estimates.push_back(stream.Process(window, sequence.calibration.camera));
  return estimates;
}

EstimatorOptions TwoIterations() {
  EstimatorOptions options = FastEstimatorOptions();
  options.num_threads = 1;
  options.max_iterations = 2;
  return options;
}

TEST(ContinuedWindowOptions, CheckRejectsOutOfRangeValues) {
  EstimatorOptions options;
  EXPECT_NO_THROW(options.Check());
  options.continued_joint_irls_iterations = -1;
  EXPECT_THROW(options.Check(), InputError);
  options = EstimatorOptions();
  options.continued_joint_cg_iterations = -1;
  EXPECT_THROW(options.Check(), InputError);
  options = EstimatorOptions();
  options.continued_pose_iterations = -1;
  EXPECT_THROW(options.Check(), InputError);
  options = EstimatorOptions();
  options.continued_max_iterations = -2;
  EXPECT_THROW(options.Check(), InputError);
  options = EstimatorOptions();
  options.continued_recentred_depth_passes = -1;
  EXPECT_THROW(options.Check(), InputError);
  options.continued_recentred_depth_passes = 11;
  EXPECT_THROW(options.Check(), InputError);
}

// The energy records of a window with n kept iterations: the initial
// structure, the first image phase, then a structure and an image record
// per iteration.
TEST(ContinuedWindowOptions, IterationsApplyToContinuedWindowsOnly) {
  EstimatorOptions options = TwoIterations();
  options.continued_max_iterations = 1;
  const std::vector<WindowEstimate> estimates = RunStream(options);
  ASSERT_EQ(estimates.size(), 2u);
  ASSERT_FALSE(estimates[0].continued);
  ASSERT_TRUE(estimates[1].continued);
  EXPECT_EQ(estimates[0].result.energies.size(), 2u + 2u * 2u);
  EXPECT_EQ(estimates[1].result.energies.size(), 2u + 2u * 1u);
}

TEST(ContinuedWindowOptions, KnobsAtTheValuesTheyReplaceChangeNothing) {
  const EstimatorOptions defaults = TwoIterations();
  EstimatorOptions same = defaults;
  same.continued_joint_irls_iterations = defaults.structure.joint_irls_iterations;
  same.continued_joint_cg_iterations = defaults.structure.joint_cg_iterations;
  same.continued_pose_iterations = defaults.structure.pose_iterations;
  same.continued_max_iterations = defaults.max_iterations;
  same.continued_recentred_depth_passes = defaults.recentred_depth_passes;
  const std::vector<WindowEstimate> a = RunStream(defaults), b = RunStream(same);
  ASSERT_EQ(a.size(), 2u);
  ASSERT_EQ(b.size(), 2u);
  EXPECT_TRUE(SameResult(a[0].result, b[0].result));
  EXPECT_TRUE(SameResult(a[1].result, b[1].result));
}

// A cheaper continued window: the first window is the same bit for bit,
// the continued one is not.
void ExpectOnlyTheContinuedWindowChanges(const EstimatorOptions& defaults, const EstimatorOptions& cheaper) {
  const std::vector<WindowEstimate> a = RunStream(defaults), b = RunStream(cheaper);
  ASSERT_EQ(a.size(), 2u);
  ASSERT_EQ(b.size(), 2u);
  EXPECT_TRUE(SameResult(a[0].result, b[0].result));
  EXPECT_FALSE(SameResult(a[1].result, b[1].result));
}

// One reweighting and one pose step in the continued window.
TEST(ContinuedWindowOptions, StructureBudgetAppliesToContinuedWindowsOnly) {
  const EstimatorOptions defaults = TwoIterations();
  EstimatorOptions cheaper = defaults;
  cheaper.continued_joint_irls_iterations = 1;
  cheaper.continued_pose_iterations = 1;
  ExpectOnlyTheContinuedWindowChanges(defaults, cheaper);
}

// One re-centred depth pass in the continued window instead of the
// default's three.
TEST(ContinuedWindowOptions, RecentredPassesApplyToContinuedWindowsOnly) {
  const EstimatorOptions defaults = TwoIterations();
  ASSERT_GT(defaults.recentred_depth_passes, 1);
  EstimatorOptions cheaper = defaults;
  cheaper.continued_recentred_depth_passes = 1;
  ExpectOnlyTheContinuedWindowChanges(defaults, cheaper);
}

// EstimatorOptions::recentred_passes_on_held_frames: by default the passes
// leave a continued window's held frames (the two shared with the first
// window). Everything before the passes is the same whatever their count,
// so the held frames' solver depth is the same bit for bit after three
// passes and after one, while the new frames' depth is not; with the option
// on, the held frames' depth differs too. The first window has no held
// frames: the option changes nothing there.
TEST(ContinuedWindowOptions, RecentredPassesLeaveTheHeldFramesByDefault) {
  const EstimatorOptions defaults = TwoIterations();
  ASSERT_TRUE(defaults.recentred_depth_pass);
  ASSERT_GT(defaults.recentred_depth_passes, 1);
  ASSERT_FALSE(defaults.recentred_passes_on_held_frames);
  EstimatorOptions one_pass = defaults;
  one_pass.continued_recentred_depth_passes = 1;
  EstimatorOptions on_held = defaults, on_held_one_pass = one_pass;
  on_held.recentred_passes_on_held_frames = on_held_one_pass.recentred_passes_on_held_frames = true;
  const std::vector<WindowEstimate> a = RunStream(defaults), b = RunStream(one_pass), c = RunStream(on_held),
                                    d = RunStream(on_held_one_pass);
  for (const auto* run : {&a, &b, &c, &d}) {
    ASSERT_EQ(run->size(), 2u);
    ASSERT_TRUE((*run)[1].continued);
    ASSERT_EQ((*run)[1].result.solver_depth.size(), 4u);
  }
  EXPECT_TRUE(SameResult(a[0].result, c[0].result));
  for (int t = 0; t < 2; ++t) {
    EXPECT_TRUE(SameBits(a[1].result.solver_depth[t], b[1].result.solver_depth[t])) << "held frame " << t;
    EXPECT_FALSE(SameBits(c[1].result.solver_depth[t], d[1].result.solver_depth[t])) << "held frame " << t;
  }
  for (int t = 2; t < 4; ++t) {
    EXPECT_FALSE(SameBits(a[1].result.solver_depth[t], b[1].result.solver_depth[t])) << "new frame " << t;
  }
}

}  // namespace
}  // namespace deblur_sr_mvs
