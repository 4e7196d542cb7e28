// Streaming layer: windowing, the bounded pending queue, pose-sequence
// alignment and the window-to-window continuity of StreamEstimator.
#include "deblur_sr_mvs/core/estimation/stream.h"

#include <atomic>
#include <cstdlib>
#include <iostream>
#include <limits>
#include <thread>

#include <unistd.h>

#include <filesystem>

#include <gtest/gtest.h>

#include "../support/test_sequences.h"
#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/evaluation/metrics.h"
#include "deblur_sr_mvs/core/imaging/image_ops.h"
#include "deblur_sr_mvs/core/io/sequence_io.h"

namespace deblur_sr_mvs {
namespace {

StreamFrame FrameWithId(uint64_t id) {
  StreamFrame frame;
  frame.id = id;
  frame.stamp_ns = static_cast<int64_t>(id) * 1000;
  return frame;
}

std::vector<uint64_t> IdsOf(const StreamWindow& window) {
  std::vector<uint64_t> ids;
  for (const StreamFrame& frame : window) ids.push_back(frame.id);
  return ids;
}

TEST(StreamOptions, RejectsBadValues) {
  StreamOptions options;
  EXPECT_NO_THROW(options.Check());
  options.window_size = 2;
  EXPECT_THROW(options.Check(), InputError);
  options = StreamOptions();
  options.window_overlap = options.window_size;
  EXPECT_THROW(options.Check(), InputError);
  options.window_overlap = 1;
  EXPECT_THROW(options.Check(), InputError);
  options = StreamOptions();
  options.max_pending_windows = 0;
  EXPECT_THROW(options.Check(), InputError);
  options = StreamOptions();
  options.window_overlap = options.window_size;
  try {
    options.Check();
    ADD_FAILURE() << "window_overlap == window_size passed";
  } catch (const InputError& error) {
    EXPECT_EQ(std::string(error.what()), "window_overlap must be in [2, 5], got 6");
  }
}

TEST(FrameWindower, OverlappingWindowsInOrder) {
  StreamOptions options;
  options.window_size = 4;
  options.window_overlap = 2;
  FrameWindower windower(options);
  std::vector<std::vector<uint64_t>> windows;
  for (uint64_t id = 0; id < 8; ++id) {
    for (const StreamWindow& window : windower.Add(FrameWithId(id))) windows.push_back(IdsOf(window));
  }
  ASSERT_EQ(windows.size(), 3u);
  EXPECT_EQ(windows[0], (std::vector<uint64_t>{0, 1, 2, 3}));
  EXPECT_EQ(windows[1], (std::vector<uint64_t>{2, 3, 4, 5}));
  EXPECT_EQ(windows[2], (std::vector<uint64_t>{4, 5, 6, 7}));
  EXPECT_EQ(windower.buffered(), 2u);
  windower.Reset();
  EXPECT_EQ(windower.buffered(), 0u);
}

TEST(FrameWindower, ShrinkingTheWindowLosesNoFrame) {
  StreamOptions options;
  options.window_size = 6;
  options.window_overlap = 2;
  FrameWindower windower(options);
  for (uint64_t id = 0; id < 5; ++id) EXPECT_TRUE(windower.Add(FrameWithId(id)).empty());
  options.window_size = 3;
  windower.SetOptions(options);
  const std::vector<StreamWindow> windows = windower.Add(FrameWithId(5));
  ASSERT_EQ(windows.size(), 4u);
  EXPECT_EQ(IdsOf(windows[0]), (std::vector<uint64_t>{0, 1, 2}));
  EXPECT_EQ(IdsOf(windows[3]), (std::vector<uint64_t>{3, 4, 5}));
}

TEST(PendingWindowQueue, DropsTheOldestAndCounts) {
  PendingWindowQueue queue(2);
  EXPECT_EQ(queue.Push({FrameWithId(1)}), 0);
  EXPECT_EQ(queue.Push({FrameWithId(2)}), 0);
  EXPECT_EQ(queue.Push({FrameWithId(3)}), 1);
  EXPECT_EQ(queue.dropped(), 1u);
  StreamWindow window;
  ASSERT_TRUE(queue.Pop(&window));
  EXPECT_EQ(window[0].id, 2u);
  ASSERT_TRUE(queue.Pop(&window));
  EXPECT_EQ(window[0].id, 3u);
  EXPECT_EQ(queue.size(), 0u);
}

TEST(PendingWindowQueue, StopWakesABlockedPop) {
  PendingWindowQueue queue(1);
  std::atomic<bool> returned{false};
  bool popped = true;
  std::thread consumer([&] {
    StreamWindow window;
    popped = queue.Pop(&window);
    returned = true;
  });
  std::this_thread::sleep_for(std::chrono::milliseconds(50));
  EXPECT_FALSE(returned.load());
  queue.Stop();
  consumer.join();
  EXPECT_FALSE(popped);
  EXPECT_EQ(queue.Push({FrameWithId(1)}), 0);  // ignored after Stop
  EXPECT_EQ(queue.size(), 0u);
}

std::vector<SE3> SomePoses() {
  std::vector<SE3> poses;
  for (int i = 0; i < 4; ++i) {
    Vector6d xi;
    xi << 0.1 * i, -0.05 * i, 0.02 * i * i, 0.01 * i, 0.03 * i, -0.02 * i;
    poses.push_back(SE3::Exp(xi));
  }
  return poses;
}

TEST(AlignPoseSequence, RecoversASimilarityExactly) {
  Sim3 truth;
  truth.scale = 2.5;
  truth.rotation = SE3::Exp((Vector6d() << 0, 0, 0, 0.3, -0.2, 0.7).finished()).rotation();
  truth.translation = Eigen::Vector3d(1.0, -2.0, 0.5);
  const std::vector<SE3> source = SomePoses();
  std::vector<SE3> target;
  for (const SE3& pose : source) target.push_back(TransformPose(truth, pose));
  const Sim3 found = AlignPoseSequence(source, target);
  EXPECT_NEAR(found.scale, truth.scale, 1e-12);
  EXPECT_LT((found.rotation - truth.rotation).norm(), 1e-12);
  EXPECT_LT((found.translation - truth.translation).norm(), 1e-12);
  // Relative poses keep their rotation and scale their translation.
  const SE3 relative_source = source[0].Inverse() * source[3];
  const SE3 relative_target = target[0].Inverse() * target[3];
  EXPECT_LT((relative_source.rotation() - relative_target.rotation()).norm(), 1e-12);
  EXPECT_LT((truth.scale * relative_source.translation() - relative_target.translation()).norm(), 1e-12);
}

TEST(AlignPoseSequence, RejectsCamerasThatDoNotMove) {
  const std::vector<SE3> still(3, SE3());
  EXPECT_THROW(AlignPoseSequence(still, SomePoses()), InputError);
  EXPECT_THROW(AlignPoseSequence(SomePoses(), still), InputError);
  EXPECT_THROW(AlignPoseSequence({SE3()}, {SE3()}), InputError);
}

EstimatorResult ResultWithSteps(const std::vector<double>& xs) {
  EstimatorResult result;
  for (double x : xs) result.T_world_cam.emplace_back(Eigen::Matrix3d::Identity(), Eigen::Vector3d(x, 0, 0));
  result.latent.push_back(cv::Mat(4, 4, CV_32FC1, cv::Scalar(0.5f)));
  return result;
}

TEST(ProblemWithEstimate, AcceptsSmoothMotionRejectsJumpsAndNonFinite) {
  EXPECT_EQ(ProblemWithEstimate(ResultWithSteps({0, 1, 2.1, 3.0, 4.2}), 8.0), "");
  EXPECT_NE(ProblemWithEstimate(ResultWithSteps({0, 1, 2, 30, 31}), 8.0), "");
  EXPECT_NE(ProblemWithEstimate(ResultWithSteps({0, 0, 0, 5}), 8.0), "");
  EXPECT_NE(ProblemWithEstimate(ResultWithSteps({0, 1, std::nan(""), 3}), 8.0), "");
  EstimatorResult bad_image = ResultWithSteps({0, 1, 2});
  bad_image.latent[0].at<float>(1, 1) = std::numeric_limits<float>::infinity();
  EXPECT_NE(ProblemWithEstimate(bad_image, 8.0), "");
}

// Synthesizes (once per binary) a small 8-frame Dolls sequence.
const Sequence& SmallSequence() {
  static const Sequence sequence =
      SynthesizedSequence("stream_seq", "Dolls", "--frames 8 --subframes 100 --hr-width 240 --hr-height 180");
  return sequence;
}

std::vector<StreamWindow> WindowsOf(const Sequence& sequence, const StreamOptions& stream_options) {
  return StreamWindowsOf(sequence.images, sequence.frames, stream_options, 100);
}

// The small sequence's frames in windows of 5 sharing 2: frames 0-4 and 3-7.
std::vector<StreamWindow> WindowsOfFiveSharingTwo(const Sequence& sequence) {
  StreamOptions stream_options;
  stream_options.window_size = 5;
  stream_options.window_overlap = 2;
  return WindowsOf(sequence, stream_options);
}

TEST(StreamEstimator, WindowsFormOneContinuousTrajectory) {
  const Sequence& sequence = SmallSequence();
  ASSERT_TRUE(sequence.ground_truth.has_value());
  const std::vector<StreamWindow> windows = WindowsOfFiveSharingTwo(sequence);
  ASSERT_EQ(windows.size(), 2u);  // frames 0-4 and 3-7

  StreamEstimator stream(FastEstimatorOptions());
  const WindowEstimate first = stream.Process(windows[0], sequence.calibration.camera);
  const WindowEstimate second = stream.Process(windows[1], sequence.calibration.camera);
  EXPECT_FALSE(first.continued);
  EXPECT_TRUE(second.continued) << second.note;
  EXPECT_EQ(first.first_new, 0);
  EXPECT_EQ(second.first_new, 2);
  EXPECT_EQ(second.ids.front(), 103u);
  EXPECT_EQ(second.stamps_ns.back(), 7 * 33000000);

  // The shared frames stay where the first window put them.
  for (int i = 0; i < 2; ++i) {
    const SE3& before = first.result.T_world_cam[3 + i];
    const SE3& after = second.result.T_world_cam[i];
    EXPECT_LT((before.translation() - after.translation()).norm(), 1e-6) << "shared frame " << i;
    EXPECT_LT((before.rotation() - after.rotation()).norm(), 1e-6) << "shared frame " << i;
  }

  // The stitched trajectory (first window + the new frames of the second)
  // matches the ground truth up to one similarity.
  std::vector<Eigen::Vector3d> estimate, truth;
  for (int t = 0; t < 5; ++t) estimate.push_back(first.result.T_world_cam[t].translation());
  for (int i = second.first_new; i < 5; ++i) estimate.push_back(second.result.T_world_cam[i].translation());
  for (const StampedPose& pose : sequence.ground_truth->poses)
    truth.push_back(pose.T_world_cam.translation());
  ASSERT_EQ(estimate.size(), truth.size());
  double path = 0.0;
  for (size_t t = 1; t < truth.size(); ++t) path += (truth[t] - truth[t - 1]).norm();
  const double ate = AbsoluteTrajectoryRmse(estimate, truth);
  EXPECT_LT(ate, 0.02 * path) << "ATE " << ate << " m over a " << path << " m path";
  std::cout << "stitched ATE " << ate << " m over a " << path << " m path\n";

  // Depth of the second window is in the same scale: a frame seen by both
  // windows has nearly the same median depth.
  const cv::Mat& depth_first = first.result.depth[4];
  const cv::Mat& depth_second = second.result.depth[1];
  auto median = [](const cv::Mat& depth) {
    std::vector<float> values;
    for (auto it = depth.begin<float>(); it != depth.end<float>(); ++it) {
      if (std::isfinite(*it) && *it > 0) values.push_back(*it);
    }
    std::nth_element(values.begin(), values.begin() + values.size() / 2, values.end());
    return values[values.size() / 2];
  };
  EXPECT_NEAR(median(depth_second) / median(depth_first), 1.0, 0.03);

  // Each image is restored once: the shared frames keep the first window's
  // latent images (they are not restarted from the bicubic up-sampling).
  EXPECT_EQ(first.warm_started, 0);
  EXPECT_EQ(second.warm_started, 2) << second.note;
  for (int i = 0; i < 2; ++i) {
    EXPECT_EQ(cv::norm(first.result.latent[3 + i], second.result.latent[i], cv::NORM_INF), 0.0)
        << "shared frame " << i;
  }

  // The new frames of the continued window are restored from the warm
  // start: sharper than their bicubic up-sampling, depth close to the truth.
  const SequenceGroundTruth& gt = *sequence.ground_truth;
  for (int i = second.first_new; i < 5; ++i) {
    const int frame = 3 + i;
    cv::Mat reference, input;
    gt.latent[frame].convertTo(reference, CV_32F, 1.0 / 255.0);
    sequence.images[frame].convertTo(input, CV_32F, 1.0 / 255.0);
    const double restored = Psnr(second.result.latent[i], reference, 1.0);
    const double bicubic = Psnr(UpsampleBicubic(input, 2), reference, 1.0);
    const DepthErrors depth = EvaluateDepth(second.result.depth[i], gt.depth[frame], DepthMetricOptions());
    std::cout << "frame " << frame << ": PSNR " << restored << " dB (bicubic " << bicubic
              << "), depth rel. error " << depth.relative_error << "\n";
    EXPECT_GT(restored, bicubic + 3.0) << "frame " << frame;
    EXPECT_LT(depth.relative_error, 0.05) << "frame " << frame;
  }
}

// The output depth's refinements (re-sweep, depth edges, consistency) run
// on the result's copies, in a stream too: the windows publish refined
// depth, but the next window starts from the solver's own depth
// (EstimatorResult::solver_depth). With the temporal fusion of the images
// off (it reads the output depth), a stream with the refinements and one
// without them estimate the same solver depth and poses in both windows, up
// to the one scale of the first window's gauge (its median depth of 1 unit
// is that of the published depth) and rounding (mean relative depth
// difference 1e-7-1e-6, against 1e-2 for the refinements themselves); the
// shared frames of the second window are not refined again (they were
// published with the first).
TEST(StreamEstimator, RefinesThePublishedDepthAndHandsOnTheSolversOwn) {
  const Sequence& sequence = SmallSequence();
  const std::vector<StreamWindow> windows = WindowsOfFiveSharingTwo(sequence);
  ASSERT_EQ(windows.size(), 2u);
  EstimatorOptions refined = FastEstimatorOptions();
  refined.fusion.radius = 0;
  refined.depth_sweep.on_output = true;
  refined.depth_sweep.before_last_structure_updates = 1;
  refined.depth_consistency.radius = 2;
  // Without the re-centred depth pass: the per-frame depth update it runs
  // (as --no-joint-depth-pose-step's) follows the window's gauge scale only
  // to about 1e-4 (the second window's solver depth moved 3e-5-1.6e-4 for
  // the first window's 3.5e-4 difference of scale, measured with either),
  // which would hide the rounding-level identity this test checks.
  refined.recentred_depth_pass = false;
  EstimatorOptions plain = refined;
  plain.depth_sweep.on_output = false;
  plain.depth_edges.on_output = false;
  plain.depth_consistency.radius = 0;
  StreamEstimator with(refined), without(plain);
  EXPECT_TRUE(with.options().depth_sweep.on_output);
  EXPECT_EQ(with.options().depth_consistency.radius, 2);
  // Not inside the iterations: not over a stream's held latents.
  EXPECT_EQ(with.options().depth_sweep.before_last_structure_updates, 0);
  double scale = 0.0;  // without / with, from the first window's gauge
  for (const StreamWindow& window : windows) {
    const WindowEstimate a = with.Process(window, sequence.calibration.camera);
    const WindowEstimate b = without.Process(window, sequence.calibration.camera);
    const size_t n = a.result.depth.size();
    ASSERT_EQ(a.result.solver_depth.size(), n);
    ASSERT_EQ(b.result.depth.size(), n);
    if (scale == 0.0) {
      scale = b.result.T_world_cam[n - 1].translation().norm() / a.result.T_world_cam[n - 1].translation().norm();
      std::cout << "gauge scale without / with the refinements: " << scale << "\n";
      EXPECT_NEAR(scale, 1.0, 0.05);
    }
    int refined_frames = 0;
    for (size_t t = 0; t < n; ++t) {
      EXPECT_LT((a.result.T_world_cam[t].rotation() - b.result.T_world_cam[t].rotation()).norm(), 1e-6)
          << "frame " << t;
      EXPECT_LT((a.result.T_world_cam[t].translation() * scale - b.result.T_world_cam[t].translation()).norm(),
                1e-6 * (1.0 + b.result.T_world_cam[t].translation().norm()))
          << "frame " << t;
      cv::Mat relative;
      cv::absdiff(a.result.solver_depth[t] * scale, b.result.depth[t], relative);
      cv::divide(relative, b.result.depth[t], relative);
      const double solver_change = cv::mean(relative)[0];
      cv::absdiff(a.result.depth[t], a.result.solver_depth[t], relative);
      cv::divide(relative, a.result.solver_depth[t], relative);
      const double refinement = cv::mean(relative)[0];
      std::cout << "frame " << t << ": solver depth " << solver_change << ", refinement " << refinement << "\n";
      EXPECT_LT(solver_change, 1e-5) << "solver depth of frame " << t;  // rounding: 1e-7-1e-6 measured
      cv::Mat differs;
      cv::compare(a.result.depth[t], a.result.solver_depth[t], differs, cv::CMP_NE);
      const int changed = cv::countNonZero(differs);
      if (static_cast<int>(t) < a.first_new) {
        EXPECT_EQ(changed, 0) << "held frame " << t << " was published with the previous window";
      } else if (changed > 0) {
        ++refined_frames;
      }
    }
    EXPECT_EQ(refined_frames, static_cast<int>(n) - a.first_new);
  }
}

TEST(StreamEstimator, ResetStartsANewSegmentAndCancelStops) {
  const Sequence& sequence = SmallSequence();
  const std::vector<StreamWindow> windows = WindowsOfFiveSharingTwo(sequence);
  StreamEstimator stream(FastEstimatorOptions());
  std::atomic<bool> cancel{true};
  stream.SetCancelFlag(&cancel);
  EXPECT_THROW(stream.Process(windows[0], sequence.calibration.camera), EstimationCancelled);
  cancel = false;
  stream.Process(windows[0], sequence.calibration.camera);
  stream.Reset();
  const WindowEstimate second = stream.Process(windows[1], sequence.calibration.camera);
  EXPECT_FALSE(second.continued);
  EXPECT_EQ(second.first_new, 0);
  EXPECT_LT(second.result.T_world_cam[0].translation().norm(), 1e-9);
}

// With a pose prior, a continued window's prior terms go through the
// window's own robust Sim(3) to the prior, with gain compensation on and
// off alike (until 2026-12-07 the stream's fit went in with it off only:
// BENCHMARKS.md "The stream's prior fit in continued windows").
TEST(StreamEstimator, ContinuedWindowsFitTheirOwnPriorAlignment) {
  const Sequence& sequence = SmallSequence();
  ASSERT_TRUE(sequence.ground_truth.has_value());
  std::vector<StreamWindow> windows = WindowsOfFiveSharingTwo(sequence);
  ASSERT_EQ(windows.size(), 2u);
  for (StreamWindow& window : windows) {
    for (StreamFrame& frame : window)
      frame.T_prior_cam = sequence.ground_truth->poses[frame.id - 100].T_world_cam;
  }
  for (const bool gain_compensation : {true, false}) {
    EstimatorOptions options = FastEstimatorOptions();
    options.gain_compensation = gain_compensation;
    StreamEstimator stream(options);
    stream.Process(windows[0], sequence.calibration.camera);
    const WindowEstimate second = stream.Process(windows[1], sequence.calibration.camera);
    ASSERT_TRUE(second.continued) << second.note;
    int prior_notes = 0;
    for (const std::string& note : second.result.notes) {
      if (note.find("pose prior in the structure update") == std::string::npos) continue;
      ++prior_notes;
      EXPECT_EQ(note.find("through the stream's alignment"), std::string::npos)
          << "gain compensation " << gain_compensation << ": " << note;
    }
    EXPECT_EQ(prior_notes, 1) << "gain compensation " << gain_compensation;
  }
}

}  // namespace
}  // namespace deblur_sr_mvs
