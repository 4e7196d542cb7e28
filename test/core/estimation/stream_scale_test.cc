// The stream keeps one scale across its windows: windows of 4 frames sharing
// 2 (the node's defaults in its rostests), one iteration, M 16, on a
// sideways-moving Dolls sequence. A continued window holds the shared poses;
// its new frames must come out in the same scale, depth and camera steps
// alike. (The pose update once slid the first new frame of each window
// towards the last held one by a third of a step, trading translation for
// rotation: the stream's scale drifted by 10 % in two windows.)
#include <algorithm>
#include <cmath>
#include <iostream>
#include <vector>

#include <gtest/gtest.h>

#include "../support/test_sequences.h"

namespace deblur_sr_mvs {
namespace {

// Stream units per metre of an estimated depth map: the median ratio to the
// ground truth (EvaluateDepth's scale maps the estimate onto the truth).
double UnitsPerMetre(const cv::Mat& depth, const cv::Mat& truth) {
  return 1.0 / EvaluateDepth(depth, truth, DepthMetricOptions()).scale;
}

TEST(StreamScale, ContinuedWindowsKeepTheScaleOfTheFirst) {
  const Sequence sequence =
      SynthesizedSequence("stream_scale", "Dolls",
                          "--frames 8 --subframes 60 --fps 30 --exposure-ratio 0.8 --hr-width 192 --hr-height 144");
  ASSERT_TRUE(sequence.ground_truth.has_value());
  const SequenceGroundTruth& truth = *sequence.ground_truth;
  StreamOptions stream_options;
  stream_options.window_size = 4;
  stream_options.window_overlap = 2;
  const std::vector<StreamWindow> windows = StreamWindowsOf(sequence.images, sequence.frames, stream_options, 0);
  ASSERT_EQ(windows.size(), 3u);  // frames 0-3, 2-5, 4-7
  EstimatorOptions options;
  options.samples = 16;
  options.max_iterations = 1;
  StreamEstimator stream(options);

  // Each frame as published (by the first window that has it as new).
  std::vector<double> units_per_metre;
  std::vector<Eigen::Vector3d> positions;
  for (const StreamWindow& window : windows) {
    const WindowEstimate estimate = stream.Process(window, sequence.calibration.camera);
    std::cout << "window " << window.front().id << "-" << window.back().id << ": " << estimate.note << "\n";
    for (const std::string& note : estimate.result.notes) std::cout << "  " << note << "\n";
    for (size_t i = estimate.first_new; i < window.size(); ++i) {
      const int t = static_cast<int>(window[i].id);
      units_per_metre.push_back(UnitsPerMetre(estimate.result.depth[i], truth.depth[t]));
      positions.push_back(estimate.result.T_world_cam[i].translation());
    }
  }
  ASSERT_EQ(positions.size(), 8u);
  double first_window = 0.0;
  for (int t = 0; t < 4; ++t) first_window += units_per_metre[t] / 4.0;
  for (int t = 0; t < 8; ++t) {
    const double step = t > 0 ? (positions[t] - positions[t - 1]).norm() /
                                    (truth.poses[t].T_world_cam.translation() -
                                     truth.poses[t - 1].T_world_cam.translation())
                                        .norm()
                              : NAN;
    std::cout << "frame " << t << ": depth " << units_per_metre[t] << " units/m, step from the previous "
              << step << " units/m\n";
    // Depth: the new frames in the first window's scale. A continued window
    // takes its scale from the shared frames' depth maps: at most 1.7 % off
    // here. Taken from the one shared camera step instead, its error (3-5 %
    // per window) added up to 6.7 % by frame 6; the slide compounded
    // 11-12 %.
    EXPECT_NEAR(units_per_metre[t] / first_window, 1.0, 0.05) << "frame " << t;
    // Camera steps: every step of the stitched trajectory in that scale too
    // (the slide left the first step of each new window 35-60 % short).
    if (t > 0) {
      EXPECT_NEAR(step / first_window, 1.0, 0.15) << "step " << t - 1 << " -> " << t;
    }
  }
}

// The same stream on Aloe, whose depth range is wide and whose initial
// structure of 4 frames varies most, on an arc and on a hand-held path (10
// frames, noise 1): every published frame's depth stays in the first
// window's scale. Measured: at most 6.1 % (arc) and 3.6 % (hand-held) off;
// tied by the path of the shared cameras instead, 21.9 % and 20.2 %
// (BENCHMARKS.md "The node's continued windows: scale from the shared
// depth").
class StreamScaleOnPath : public testing::TestWithParam<const char*> {};

TEST_P(StreamScaleOnPath, DepthKeepsTheScaleOfTheFirstWindow) {
  const std::string path = GetParam();
  const Sequence sequence = SynthesizedSequence("stream_scale_" + path, "Aloe",
                                                "--frames 10 --subframes 60 --fps 30 --exposure-ratio 0.8 "
                                                "--hr-width 192 --hr-height 144 --noise 1 --seed 0 --path " +
                                                    path);
  ASSERT_TRUE(sequence.ground_truth.has_value());
  StreamOptions stream_options;
  stream_options.window_size = 4;
  stream_options.window_overlap = 2;
  const std::vector<StreamWindow> windows = StreamWindowsOf(sequence.images, sequence.frames, stream_options, 0);
  ASSERT_EQ(windows.size(), 4u);  // frames 0-3, 2-5, 4-7, 6-9
  EstimatorOptions options;
  options.samples = 16;
  options.max_iterations = 1;
  StreamEstimator stream(options);
  std::vector<double> units_per_metre;
  for (const StreamWindow& window : windows) {
    const WindowEstimate estimate = stream.Process(window, sequence.calibration.camera);
    EXPECT_EQ(estimate.continued, window.front().id > 0) << estimate.note;
    for (size_t i = estimate.first_new; i < window.size(); ++i) {
      const int t = static_cast<int>(window[i].id);
      units_per_metre.push_back(UnitsPerMetre(estimate.result.depth[i], sequence.ground_truth->depth[t]));
    }
  }
  ASSERT_EQ(units_per_metre.size(), 10u);
  const double first_window =
      (units_per_metre[0] + units_per_metre[1] + units_per_metre[2] + units_per_metre[3]) / 4.0;
  for (int t = 0; t < 10; ++t) {
    std::cout << path << " frame " << t << ": depth " << units_per_metre[t] / first_window
              << " x the first window's units/m\n";
    EXPECT_NEAR(units_per_metre[t] / first_window, 1.0, 0.10) << path << " frame " << t;
  }
}

INSTANTIATE_TEST_SUITE_P(AloePaths, StreamScaleOnPath, testing::Values("arc", "handheld"));

}  // namespace
}  // namespace deblur_sr_mvs
