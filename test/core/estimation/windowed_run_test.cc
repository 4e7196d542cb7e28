// A sequence estimated in overlapping windows (EstimateInWindows): how the
// windows are cut, and that the stitched result is the stream's, frame for
// frame, as accurate as one window, in one world and scale.
#include "deblur_sr_mvs/core/estimation/windowed_run.h"

#include <algorithm>
#include <iostream>

#include <gtest/gtest.h>

#include "../support/same_bits.h"
#include "../support/test_sequences.h"
#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/estimation/initializer.h"
#include "deblur_sr_mvs/core/evaluation/metrics.h"

namespace deblur_sr_mvs {
namespace {

WindowedRunOptions Windowing(int size, int overlap) {
  WindowedRunOptions options;
  options.window_size = size;
  options.window_overlap = overlap;
  return options;
}

// Every frame count, window size and overlap in a range: the windows cover
// the sequence in order, are as few as windows of window_size frames sharing
// window_overlap can be, of one size within [3, window_size], and neighbours
// share at least window_overlap frames.
TEST(WindowRanges, FewestEvenWindowsThatCoverWithTheOverlap) {
  for (int size = 3; size <= 24; ++size) {
    for (int overlap = 2; overlap < size; ++overlap) {
      for (int frames = 1; frames <= 80; ++frames) {
        const std::vector<FrameRange> ranges = WindowRanges(frames, Windowing(size, overlap));
        const std::string where = "size " + std::to_string(size) + ", overlap " + std::to_string(overlap) +
                                  ", frames " + std::to_string(frames);
        ASSERT_FALSE(ranges.empty()) << where;
        EXPECT_EQ(ranges.front().first, 0) << where;
        EXPECT_EQ(ranges.back().last, frames - 1) << where;
        if (frames <= size) {
          EXPECT_EQ(ranges.size(), 1u) << where;
          continue;
        }
        // Fewest: k - 1 windows of `size` sharing `overlap` cover less.
        const int count = static_cast<int>(ranges.size());
        EXPECT_LT((count - 1) * size - (count - 2) * overlap, frames) << where;
        const int length = ranges.front().last - ranges.front().first + 1;
        EXPECT_GE(length, 3) << where;
        EXPECT_LE(length, size) << where;
        for (size_t w = 0; w < ranges.size(); ++w) {
          EXPECT_EQ(ranges[w].last - ranges[w].first + 1, length) << where << ", window " << w;
          if (w == 0) continue;
          EXPECT_GT(ranges[w].first, ranges[w - 1].first) << where;
          EXPECT_GE(ranges[w - 1].last - ranges[w].first + 1, overlap) << where << ", window " << w;
        }
      }
    }
  }
}

TEST(WindowRanges, OneWindowWhenOffAndBadOptionsRejected) {
  EXPECT_EQ(WindowRanges(200, Windowing(0, 2)).size(), 1u);
  EXPECT_EQ(WindowRanges(200, Windowing(0, 2)).back().last, 199);
  EXPECT_TRUE(WindowRanges(0, Windowing(10, 2)).empty());
  // 22 frames in windows of at most 20 sharing 2: two of 12, not 20 + 20.
  const std::vector<FrameRange> ranges = WindowRanges(22, Windowing(20, 2));
  ASSERT_EQ(ranges.size(), 2u);
  EXPECT_EQ(ranges[0].last, 11);
  EXPECT_EQ(ranges[1].first, 10);
  EXPECT_THROW(WindowRanges(10, Windowing(2, 1)), InputError);  // a window needs 3 frames
  EXPECT_THROW(WindowRanges(10, Windowing(6, 6)), InputError);  // windows must advance
  EXPECT_THROW(WindowRanges(10, Windowing(6, 1)), InputError);  // two shared frames fix the scale
  EXPECT_THROW(Windowing(-1, 2).Check(), InputError);
}

// An 8-frame hand-held sequence in windows of at most 5 sharing 2 (frames
// 0-4 and 3-7), not tied to the sequence's trajectory: every frame is given out once, frame for frame what
// the StreamEstimator gives for those windows, restored and with depth as in the stream test, on one
// trajectory.
TEST(EstimateInWindows, StitchesTheStreamsWindowsIntoOneResult) {
  const Sequence sequence = SynthesizedSequence(
      "windowed", "Dolls", "--frames 8 --subframes 60 --hr-width 192 --hr-height 144 --noise 1 --seed 2");
  ASSERT_TRUE(sequence.ground_truth.has_value());
  EstimatorOptions options = FastEstimatorOptions();
  options.num_threads = 1;  // bit for bit against the stream below
  const EstimatorInput input = InputOf(sequence);
  std::vector<WindowRecord> windows;
  std::vector<double> progress;
  WindowedRunOptions windowing = Windowing(5, 2);
  windowing.tie_to_sequence_trajectory = false;  // the stream's windows as they are
  const EstimatorResult result = EstimateInWindows(
      input, options, windowing,
      [&progress](double fraction, const std::string&) { progress.push_back(fraction); }, &windows);

  ASSERT_EQ(windows.size(), 2u);
  EXPECT_EQ(windows[0].frames.first, 0);
  EXPECT_EQ(windows[0].frames.last, 4);
  EXPECT_EQ(windows[1].frames.first, 3);
  EXPECT_EQ(windows[1].frames.last, 7);
  EXPECT_FALSE(windows[0].continued);
  EXPECT_TRUE(windows[1].continued) << windows[1].note;
  EXPECT_EQ(windows[1].first_output, 4);  // frames 3-4 shared: 3 from the first window, 4 from the second
  EXPECT_FALSE(windows[1].energies.empty());
  // Progress runs over the windows: the second window's reports lie in its half.
  ASSERT_FALSE(progress.empty());
  EXPECT_GE(*std::min_element(progress.begin(), progress.end()), 0.0);
  EXPECT_LE(*std::max_element(progress.begin(), progress.end()), 1.0);
  EXPECT_GE(progress.back(), 0.5);

  ASSERT_EQ(result.latent.size(), 8u);
  ASSERT_EQ(result.depth.size(), 8u);
  ASSERT_EQ(result.solver_depth.size(), 8u);
  ASSERT_EQ(result.T_world_cam.size(), 8u);
  ASSERT_EQ(result.frame_gains.size(), 8u);
  EXPECT_EQ(result.frame_gains.front(), 1.0);
  EXPECT_TRUE(result.depth_observable);

  // The same windows through the stream: frames 0-3 from the first, 4-7
  // from the second, bit for bit; the second window held frame 4's restored
  // image and pose.
  StreamOptions stream_options;
  stream_options.window_size = 5;
  stream_options.window_overlap = 2;
  const std::vector<StreamWindow> stream_windows =
      StreamWindowsOf(sequence.images, sequence.frames, stream_options, 0);
  ASSERT_EQ(stream_windows.size(), 2u);
  StreamEstimator stream(options);
  const WindowEstimate first = stream.Process(stream_windows[0], input.camera);
  const WindowEstimate second = stream.Process(stream_windows[1], input.camera);
  EXPECT_EQ(cv::norm(first.result.latent[4], second.result.latent[1], cv::NORM_INF), 0.0);
  EXPECT_EQ((first.result.T_world_cam[4].translation() - second.result.T_world_cam[1].translation()).norm(),
            0.0);
  for (int t = 0; t < 8; ++t) {
    const EstimatorResult& window = t < 4 ? first.result : second.result;
    const int i = t < 4 ? t : t - 3;
    EXPECT_TRUE(SameBits(result.depth[t], window.depth[i])) << "frame " << t;
    EXPECT_EQ(cv::norm(result.latent[t], window.latent[i], cv::NORM_INF), 0.0) << "frame " << t;
    EXPECT_EQ((result.T_world_cam[t].translation() - window.T_world_cam[i].translation()).norm(), 0.0)
        << "frame " << t;
  }

  // Restored, with depth, on one trajectory (the stream test's bounds).
  const SequenceGroundTruth& gt = *sequence.ground_truth;
  std::vector<Eigen::Vector3d> estimate, truth;
  for (int t = 0; t < 8; ++t) {
    cv::Mat reference, bicubic_input;
    gt.latent[t].convertTo(reference, CV_32F, 1.0 / 255.0);
    input.images[t].copyTo(bicubic_input);
    const double restored = Psnr(result.latent[t], reference, 1.0);
    const double bicubic = Psnr(UpsampleBicubic(bicubic_input, 2), reference, 1.0);
    const DepthErrors depth = EvaluateDepth(result.depth[t], gt.depth[t], DepthMetricOptions());
    std::cout << "frame " << t << ": PSNR " << restored << " dB (bicubic " << bicubic
              << "), depth rel. error " << depth.relative_error << "\n";
    EXPECT_GT(restored, bicubic + 3.0) << "frame " << t;
    EXPECT_LT(depth.relative_error, 0.05) << "frame " << t;
    estimate.push_back(result.T_world_cam[t].translation());
    truth.push_back(gt.poses[t].T_world_cam.translation());
  }
  double path = 0.0;
  for (size_t t = 1; t < truth.size(); ++t) path += (truth[t] - truth[t - 1]).norm();
  const double ate = AbsoluteTrajectoryRmse(estimate, truth);
  std::cout << "stitched ATE " << ate << " m over a " << path << " m path\n";
  EXPECT_LT(ate, 0.02 * path);
}

// RMS distance (Sim(3)-aligned) of `result`'s camera centres from `poses`.
double TrajectoryDistance(const EstimatorResult& result, const std::vector<SE3>& poses) {
  std::vector<Eigen::Vector3d> estimate, reference;
  for (size_t t = 0; t < result.T_world_cam.size(); ++t) {
    estimate.push_back(result.T_world_cam[t].translation());
    reference.push_back(poses[t].translation());
  }
  return AbsoluteTrajectoryRmse(estimate, reference);
}

// A 24-frame hand-held sequence in 8 windows of 5 sharing 2, whose camera
// barely translates over frames 3-10 (those two windows have no parallax):
// tied to the whole sequence's trajectory (the default), the stitched
// cameras lie closer to that trajectory (InitializeTrajectory) than the
// windows' chain alone does, the windows without parallax take their
// camera centres from it instead of holding one, so the ATE is a fraction
// of the chain's (measured 0.00246 against 0.01150 m; one window of every
// frame: 0.00241), and the result says how it was tied; a pose prior of
// the input's own replaces the tie.
TEST(EstimateInWindows, TheSequencesTrajectoryTiesTheWindows) {
  const Sequence sequence =
      SynthesizedSequence("windowed_tie", "Dolls",
                          "--frames 24 --subframes 60 --hr-width 192 --hr-height 144 --noise 1 --seed 4 "
                          "--path handheld --blur-px 5");
  ASSERT_TRUE(sequence.ground_truth.has_value());
  EstimatorOptions options = FastEstimatorOptions();
  options.max_iterations = 0;  // the poses of the initialisation: what the tie acts on
  const EstimatorInput input = InputOf(sequence);
  WindowedRunOptions windowing = Windowing(5, 2);
  ASSERT_EQ(WindowRanges(24, windowing).size(), 8u);
  std::vector<WindowRecord> windows;
  const EstimatorResult tied = EstimateInWindows(input, options, windowing, nullptr, &windows);
  windowing.tie_to_sequence_trajectory = false;
  const EstimatorResult chained = EstimateInWindows(input, options, windowing, nullptr);
  ASSERT_EQ(tied.T_world_cam.size(), 24u);
  ASSERT_EQ(chained.T_world_cam.size(), 24u);

  const InitialTrajectory trajectory =
      InitializeTrajectory(input.images, input.camera, input.frames, options.initializer);
  const double tied_distance = TrajectoryDistance(tied, trajectory.T_world_cam);
  const double chained_distance = TrajectoryDistance(chained, trajectory.T_world_cam);
  std::vector<SE3> truth;
  for (const StampedPose& pose : sequence.ground_truth->poses) truth.push_back(pose.T_world_cam);
  const double tied_ate = TrajectoryDistance(tied, truth);
  const double chained_ate = TrajectoryDistance(chained, truth);
  std::cout << "from the sequence's trajectory: tied " << tied_distance << ", chained " << chained_distance
            << " (its units); ATE: tied " << tied_ate << " m, chained " << chained_ate << " m\n";
  EXPECT_LT(tied_distance, chained_distance);
  EXPECT_LT(tied_ate, 0.5 * chained_ate);
  int placed = 0;
  for (const WindowRecord& window : windows) {
    placed += window.note.find("camera positions from the pose prior") != std::string::npos;
  }
  EXPECT_GE(placed, 1) << "a window without parallax follows the trajectory";
  ASSERT_FALSE(tied.notes.empty());
  EXPECT_NE(tied.notes.front().find("windows tied to the whole sequence's trajectory"), std::string::npos)
      << tied.notes.front();
  for (const std::string& note : chained.notes) EXPECT_EQ(note.find("tied"), std::string::npos) << note;

  // A prior of the input's own (here the ground truth) on 8 frames, 2 windows.
  EstimatorInput with_prior = WindowInputOf(input, {0, 7});
  for (int t = 0; t < 8; ++t) with_prior.T_prior_cam.push_back(truth[t]);
  windowing.tie_to_sequence_trajectory = true;
  const EstimatorResult by_prior = EstimateInWindows(with_prior, options, windowing, nullptr);
  ASSERT_FALSE(by_prior.notes.empty());
  EXPECT_EQ(by_prior.notes.front(), "windows tied by the input's pose prior");
}

}  // namespace
}  // namespace deblur_sr_mvs
