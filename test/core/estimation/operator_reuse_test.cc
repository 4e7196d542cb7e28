// Capture operators carried from one window of a stream to the next
// (EstimatorOptions::carried_frames, EstimatorInput::carried_operators): a
// carried operator is the one a build gives, and a window that uses them
// gives the same result, bit for bit, as one that builds everything.
#include <cstring>
#include <iostream>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "../support/same_bits.h"
#include "../support/test_sequences.h"
#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/estimation/estimator.h"
#include "deblur_sr_mvs/core/estimation/stream.h"

namespace deblur_sr_mvs {
namespace {

const Sequence& SmallSequence() {
  static const Sequence sequence =
      SynthesizedSequence("reuse_seq", "Dolls", "--frames 8 --subframes 100 --hr-width 240 --hr-height 180");
  return sequence;
}

template <typename T>
bool SameArray(const T* a, const T* b, size_t count) {
  return std::memcmp(a, b, count * sizeof(T)) == 0;
}

// The CSR arrays and the coverage, compared as bytes.
void ExpectSameOperator(const CaptureOperator& a, const CaptureOperator& b) {
  const SparseMatrixRM ma = a.matrix().ToCsr();
  const SparseMatrixRM mb = b.matrix().ToCsr();
  ASSERT_EQ(ma.rows(), mb.rows());
  ASSERT_EQ(ma.cols(), mb.cols());
  ASSERT_EQ(ma.nonZeros(), mb.nonZeros());
  EXPECT_TRUE(SameArray(ma.outerIndexPtr(), mb.outerIndexPtr(), ma.rows() + 1));
  EXPECT_TRUE(SameArray(ma.innerIndexPtr(), mb.innerIndexPtr(), ma.nonZeros()));
  EXPECT_TRUE(SameArray(ma.valuePtr(), mb.valuePtr(), ma.nonZeros()));
  ASSERT_EQ(a.coverage().size(), b.coverage().size());
  EXPECT_TRUE(SameArray(a.coverage().data(), b.coverage().data(), a.coverage().size()));
}

void ExpectSameResult(const EstimatorResult& a, const EstimatorResult& b) {
  ASSERT_EQ(a.latent.size(), b.latent.size());
  for (size_t t = 0; t < a.latent.size(); ++t) {
    EXPECT_TRUE(SameBits(a.latent[t], b.latent[t])) << "latent " << t;
    EXPECT_TRUE(SameBits(a.depth[t], b.depth[t])) << "depth " << t;
    EXPECT_TRUE(a.T_world_cam[t].rotation() == b.T_world_cam[t].rotation()) << "pose " << t;
    EXPECT_TRUE(a.T_world_cam[t].translation() == b.T_world_cam[t].translation()) << "pose " << t;
  }
  ASSERT_EQ(a.energies.size(), b.energies.size());
  for (size_t i = 0; i < a.energies.size(); ++i) EXPECT_EQ(a.energies[i].total, b.energies[i].total) << i;
}

const char kBuildStage[] = "operator builds (thread seconds)";

double StageSeconds(const EstimatorResult& result, const std::string& stage) {
  for (const StageTiming& timing : result.timings) {
    if (timing.stage == stage) return timing.seconds;
  }
  return 0.0;
}

// The first `count` frames from `first` on, as the estimator's input.
EstimatorInput InputOfFrames(const Sequence& sequence, int first, int count) {
  const EstimatorInput all = InputOf(sequence);
  EstimatorInput input;
  input.camera = all.camera;
  input.readout_time = all.readout_time;
  for (int t = first; t < first + count; ++t) {
    input.images.push_back(all.images[t]);
    input.frames.push_back(all.frames[t]);
  }
  return input;
}

TEST(OperatorReuse, OptionsRejectANegativeCount) {
  EstimatorOptions options;
  options.carried_frames = -1;
  try {
    options.Check();
    ADD_FAILURE() << "carried_frames -1 passed";
  } catch (const InputError& error) {
    EXPECT_NE(std::string(error.what()).find("carried_frames"), std::string::npos) << error.what();
  }
  options.carried_frames = 3;
  EXPECT_NO_THROW(options.Check());
  StreamEstimator stream(FastEstimatorOptions());
  EXPECT_THROW(stream.SetWindowOverlap(-1), InputError);
  EXPECT_NO_THROW(stream.SetWindowOverlap(0));
}

// Two windows of 5 frames sharing 4, as the stream runs them (the second
// holds the shared poses and latent images and starts from their solver
// depths, EstimatorResult::solver_depth, the output's being refined).
// An interior frame's blur path runs through two frames before it and one
// after it (BlurPathFrames), so the first window hands on the operators of
// the one frame whose path lies among the shared frames and stays so in the
// second window (frame 3: path 1-4 in both; frame 2's path runs through
// frame 0 in the first window and frame 4 in the second; frame 4, the last,
// gains frame 5): Psi_3 sampling I_2, I_3 and I_4, each equal to a fresh
// build from the structure it carries, and the second window gives the same
// result with them as without.
TEST(OperatorReuse, CarriedOperatorsEqualRebuiltOnesAndChangeNothing) {
  const Sequence& sequence = SmallSequence();
  ASSERT_TRUE(sequence.ground_truth.has_value());
  const SequenceGroundTruth& gt = *sequence.ground_truth;
  EstimatorOptions options = FastEstimatorOptions();
  options.keep_input_gauge = true;
  options.carried_frames = 4;
  std::vector<cv::Mat> depth;
  std::vector<SE3> poses;
  for (int t = 0; t < 5; ++t) {
    depth.push_back(gt.depth[t].clone());
    poses.push_back(gt.poses[t].T_world_cam);
  }
  const EstimatorResult first =
      Estimator(options).RunFromStructure(InputOfFrames(sequence, 0, 5), depth, poses);
  EXPECT_EQ(first.operators_reused, 0);
  ASSERT_EQ(first.carried_operators.size(), 3u);  // Psi_3 sampling I_2, I_3 and I_4
  CaptureOperatorOptions build_options = first.carried_operators[0].options;
  build_options.num_threads = 1;
  build_options.transposed_copy = false;
  for (const CarriedOperator& carried : first.carried_operators) {
    ExpectSameOperator(carried.entry->op, BuildCaptureOperator(carried.geometry, build_options));
    EXPECT_TRUE(SameBits(carried.geometry.depth_hr, first.solver_depth[3]));
  }

  EstimatorOptions second_options = options;
  second_options.fixed_leading_poses = 4;
  second_options.held_leading_latents = 4;
  EstimatorInput input = InputOfFrames(sequence, 1, 5);
  input.initial_latents = {first.latent[1], first.latent[2], first.latent[3], first.latent[4]};
  const std::vector<cv::Mat> second_depth = {first.solver_depth[1], first.solver_depth[2],
                                             first.solver_depth[3], first.solver_depth[4],
                                             gt.depth[5].clone()};
  const std::vector<SE3> second_poses = {first.T_world_cam[1], first.T_world_cam[2], first.T_world_cam[3],
                                         first.T_world_cam[4], gt.poses[5].T_world_cam};
  const EstimatorResult rebuilt =
      Estimator(second_options).RunFromStructure(input, second_depth, second_poses);
  input.carried_operators = first.carried_operators;
  const EstimatorResult reused =
      Estimator(second_options).RunFromStructure(input, second_depth, second_poses);
  EXPECT_EQ(rebuilt.operators_reused, 0);
  EXPECT_EQ(reused.operators_reused, 3);
  ExpectSameResult(reused, rebuilt);

  // A structure that differs in one pixel is not reused.
  std::vector<cv::Mat> nudged = second_depth;
  nudged[2] = second_depth[2].clone();
  nudged[2].at<float>(90, 120) *= 1.01f;
  EXPECT_EQ(Estimator(second_options).RunFromStructure(input, nudged, second_poses).operators_reused, 0);
}

// The stream: windows of 5 sharing 4 on the first 7 frames (windows 0-4,
// 1-5, 2-6). The third window uses the second's operators of its frame 2
// (frame 3 of the second window, whose blur path runs through the shared
// frames on both sides); with the hand-over switched off (overlap 0) every
// window is the same bit for bit. At the stream's default overlap of 2 no
// frame's path lies among the shared frames in both windows: nothing is
// reused (with the quadratic paths before 2026-12-06 an overlap of 3 was
// enough).
TEST(OperatorReuse, StreamWindowsAreTheSameWithAndWithoutReuse) {
  const Sequence& sequence = SmallSequence();
  const std::vector<cv::Mat> images(sequence.images.begin(), sequence.images.begin() + 7);
  const std::vector<FrameRecord> frames(sequence.frames.begin(), sequence.frames.begin() + 7);
  StreamOptions stream_options;
  stream_options.window_size = 5;
  stream_options.window_overlap = 4;
  const std::vector<StreamWindow> windows = StreamWindowsOf(images, frames, stream_options, 100);
  ASSERT_EQ(windows.size(), 3u);
  // One thread: the pose update's sums then run in one order, and two runs
  // of a window are the same bit for bit.
  EstimatorOptions options = FastEstimatorOptions();
  options.num_threads = 1;
  StreamEstimator reusing(options);
  reusing.SetWindowOverlap(stream_options.window_overlap);
  StreamEstimator building(options);
  building.SetWindowOverlap(0);
  int reused = 0;
  for (const StreamWindow& window : windows) {
    const WindowEstimate a = reusing.Process(window, sequence.calibration.camera);
    const WindowEstimate b = building.Process(window, sequence.calibration.camera);
    EXPECT_EQ(b.result.operators_reused, 0);
    EXPECT_TRUE(a.result.carried_operators.empty());  // kept by the stream
    reused += a.result.operators_reused;
    ExpectSameResult(a.result, b.result);
    std::cout << "window " << a.ids.front() << "-" << a.ids.back() << ": " << a.result.operators_reused
              << " operators reused; operator builds " << StageSeconds(a.result, kBuildStage)
              << " thread-s against " << StageSeconds(b.result, kBuildStage) << " thread-s building all\n";
  }
  // The first window starts a segment (output gauge): nothing is carried
  // from it; the second hands 3 operators (Psi of its frame 3 sampling its
  // frames 2-4) to the third.
  EXPECT_EQ(reused, 3);
}

}  // namespace
}  // namespace deblur_sr_mvs
