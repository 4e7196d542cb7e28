// StructureUpdateOptions::skip_held_pose_work: a pair between two frames
// whose poses are held (a stream window's frames shared with the previous
// window) enters only the held poses' rows of the pose systems, so its pose
// terms are not formed. The joint depth + pose step, the pose update and a
// continued stream window give the same results bit for bit with and
// without the saving. The joint step's other exact savings (a restored pair
// and its input pair form their pose terms in one pass, the reduced camera
// system's products are formed frame by frame in parallel) keep its results
// too: the same bits on one and two threads.
#include <cstring>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "../support/same_bits.h"
#include "../support/test_sequences.h"
#include "deblur_sr_mvs/core/estimation/estimator.h"
#include "deblur_sr_mvs/core/estimation/stream.h"
#include "deblur_sr_mvs/core/estimation/structure_update.h"

namespace deblur_sr_mvs {
namespace {

bool SamePose(const SE3& a, const SE3& b) {
  return a.rotation() == b.rotation() && a.translation() == b.translation();
}

// Four cameras along a sideways path over a textured slanted plane; each
// frame's image and inverse depth from ray-plane intersections.
struct FourFrames {
  PinholeCamera camera{96, 72, 80.0, 82.0, 47.3, 35.6};
  std::vector<SE3> T_world_cam;
  std::vector<cv::Mat> images, inverse_depths;

  FourFrames() {
    const Eigen::Vector3d normal(-0.3, 0.1, 1.0);
    for (int f = 0; f < 4; ++f) {
      T_world_cam.push_back(
          SE3::Exp((Vector6d() << 0.06 * f, 0.005 * f, 0.003 * f, 0.004 * f, -0.008 * f, 0.002 * f).finished()));
      const SE3& pose = T_world_cam.back();
      cv::Mat image(camera.height, camera.width, CV_32FC3), inverse_depth(camera.height, camera.width, CV_32FC1);
      for (int y = 0; y < camera.height; ++y) {
        for (int x = 0; x < camera.width; ++x) {
          const Eigen::Vector3d ray = pose.rotation() * camera.Ray(x, y);
          const double depth = (2.0 - normal.dot(pose.translation())) / normal.dot(ray);
          const Eigen::Vector3d point = pose.translation() + depth * ray;
          inverse_depth.at<float>(y, x) = static_cast<float>(1.0 / depth);
          const double u = point.x() / 0.025, v = point.y() / 0.025;
          image.at<cv::Vec3f>(y, x) = cv::Vec3f(static_cast<float>(0.5 + 0.4 * std::sin(0.08 * u + 0.03 * v)),
                                                static_cast<float>(0.5 + 0.4 * std::cos(0.07 * v - 0.02 * u)),
                                                static_cast<float>(0.5 + 0.3 * std::sin(0.05 * (u + v))));
        }
      }
      images.push_back(image);
      inverse_depths.push_back(inverse_depth);
    }
  }

  // Every ordered pair (t <- s) within two frames, on the HR images.
  std::vector<FrameDepthTerms> Terms() const {
    std::vector<FrameDepthTerms> terms(4);
    for (int t = 0; t < 4; ++t) {
      for (int s = std::max(0, t - 2); s <= std::min(3, t + 2); ++s) {
        if (s == t) continue;
        PairMatching pair;
        pair.t = t;
        pair.s = s;
        pair.observation = &images[t];
        terms[t].pairs.push_back(pair);
      }
    }
    return terms;
  }

  // The free frames (2, 3) moved off their poses, and every depth 5 % off.
  void Perturb(std::vector<SE3>* poses, std::vector<cv::Mat>* rho) const {
    *poses = T_world_cam;
    (*poses)[2] = SE3::Exp((Vector6d() << 0.0, 0.004, 0.003, 0.003, -0.002, 0.001).finished()) * (*poses)[2];
    (*poses)[3] = SE3::Exp((Vector6d() << 0.002, -0.003, 0.0, -0.002, 0.002, 0.0).finished()) * (*poses)[3];
    rho->clear();
    for (const cv::Mat& r : inverse_depths) rho->push_back(r * 1.05);
  }
};

constexpr int kHeldPoses = 2;

// Two runs' poses and depths are the same bits, and the run moved every
// depth and the free frame 3 away from the perturbed start.
void ExpectSameMovedResults(const FourFrames& scene, const std::vector<std::vector<SE3>>& poses,
                            const std::vector<std::vector<cv::Mat>>& rho) {
  std::vector<SE3> start;
  std::vector<cv::Mat> start_rho;
  scene.Perturb(&start, &start_rho);
  for (int f = 0; f < 4; ++f) {
    EXPECT_TRUE(SamePose(poses[0][f], poses[1][f])) << "pose " << f;
    EXPECT_TRUE(SameBits(rho[0][f], rho[1][f])) << "inverse depth " << f;
    EXPECT_FALSE(SameBits(rho[1][f], start_rho[f])) << "the step moved inverse depth " << f;
  }
  EXPECT_FALSE(SamePose(poses[1][3], start[3]));  // free: moved
}

// Terms() and, right after each pair, a second HR pair that warps another
// image pair (`sources`[s] into `sources`[t]), as the estimator lays out a
// restored pair and its input pair (the two form their pose terms in one
// pass).
std::vector<FrameDepthTerms> TermsWithSources(const FourFrames& scene, const std::vector<cv::Mat>& sources) {
  std::vector<FrameDepthTerms> terms = scene.Terms();
  for (FrameDepthTerms& frame : terms) {
    const std::vector<PairMatching> restored = frame.pairs;
    frame.pairs.clear();
    for (PairMatching pair : restored) {
      frame.pairs.push_back(pair);
      pair.observation = &sources[pair.t];
      pair.source = &sources[pair.s];
      frame.pairs.push_back(pair);
    }
  }
  return terms;
}

// The joint step from the perturbed start with `threads` threads.
void JointStep(const FourFrames& scene, const std::vector<FrameDepthTerms>& terms, int threads,
               std::vector<SE3>* poses, std::vector<cv::Mat>* rho) {
  StructureUpdateOptions options;
  options.num_threads = threads;
  scene.Perturb(poses, rho);
  UpdateDepthAndPoses(scene.camera, scene.images, terms, scene.camera.fx * 0.06, options, 1, poses, rho);
}

// Gray versions of the frames' images, a little brighter: the second image pair.
std::vector<cv::Mat> SecondImages(const FourFrames& scene) {
  std::vector<cv::Mat> sources;
  for (const cv::Mat& image : scene.images) {
    cv::Mat gray;
    cv::cvtColor(image, gray, cv::COLOR_BGR2GRAY);
    cv::Mat colour;
    cv::merge(std::vector<cv::Mat>(3, gray * 0.9 + 0.05), colour);
    sources.push_back(colour);
  }
  return sources;
}

TEST(JointStepThreads, OneAndTwoThreadsGiveTheSameBits) {
  const FourFrames scene;
  const std::vector<cv::Mat> sources = SecondImages(scene);
  const std::vector<FrameDepthTerms> terms = TermsWithSources(scene, sources);
  std::vector<std::vector<SE3>> poses(2);
  std::vector<std::vector<cv::Mat>> rho(2);
  for (int threads : {1, 2}) JointStep(scene, terms, threads, &poses[threads - 1], &rho[threads - 1]);
  ExpectSameMovedResults(scene, poses, rho);
}

TEST(HeldPoseWork, JointStepIsTheSameWithoutTheHeldPairsPoseTerms) {
  const FourFrames scene;
  const std::vector<FrameDepthTerms> terms = scene.Terms();
  std::vector<std::vector<SE3>> poses(2);
  std::vector<std::vector<cv::Mat>> rho(2);
  for (int skip = 0; skip < 2; ++skip) {
    StructureUpdateOptions options;
    options.num_threads = 1;
    options.skip_held_pose_work = skip == 1;
    scene.Perturb(&poses[skip], &rho[skip]);
    UpdateDepthAndPoses(scene.camera, scene.images, terms, scene.camera.fx * 0.06, options, kHeldPoses,
                        &poses[skip], &rho[skip]);
  }
  ExpectSameMovedResults(scene, poses, rho);
  std::vector<SE3> start;
  std::vector<cv::Mat> start_rho;
  scene.Perturb(&start, &start_rho);
  EXPECT_TRUE(SamePose(poses[1][1], start[1]));  // held
}

TEST(HeldPoseWork, PoseUpdateIsTheSameWithoutTheHeldPairs) {
  const FourFrames scene;
  std::vector<PairMatching> pairs;
  for (const FrameDepthTerms& frame : scene.Terms()) pairs.insert(pairs.end(), frame.pairs.begin(), frame.pairs.end());
  std::vector<std::vector<SE3>> poses(2);
  for (int skip = 0; skip < 2; ++skip) {
    StructureUpdateOptions options;
    options.skip_held_pose_work = skip == 1;
    std::vector<cv::Mat> unused_rho;
    scene.Perturb(&poses[skip], &unused_rho);
    UpdatePoses(scene.camera, scene.inverse_depths, scene.images, pairs, options, &poses[skip], kHeldPoses);
  }
  std::vector<SE3> start;
  std::vector<cv::Mat> unused_rho;
  scene.Perturb(&start, &unused_rho);
  for (int f = 0; f < 4; ++f) EXPECT_TRUE(SamePose(poses[0][f], poses[1][f])) << "pose " << f;
  EXPECT_FALSE(SamePose(poses[1][2], start[2]));
}

// A continued window (windows of 4 sharing 2: frames 0-3, then 2-5) with
// the default structure update (joint step, pose update over the pose
// radius), one thread.
TEST(HeldPoseWork, ContinuedStreamWindowIsTheSameBitForBit) {
  const Sequence sequence =
      SynthesizedSequence("held_pose_work", "Dolls", "--frames 6 --subframes 60 --hr-width 192 --hr-height 144");
  StreamOptions stream_options;
  stream_options.window_size = 4;
  stream_options.window_overlap = 2;
  const std::vector<StreamWindow> windows = StreamWindowsOf(sequence.images, sequence.frames, stream_options, 0);
  ASSERT_EQ(windows.size(), 2u);
  std::vector<WindowEstimate> second(2);
  for (int skip = 0; skip < 2; ++skip) {
    EstimatorOptions options = FastEstimatorOptions();
    options.num_threads = 1;
    options.structure.skip_held_pose_work = skip == 1;
    StreamEstimator stream(options);
    stream.Process(windows[0], sequence.calibration.camera);
    second[skip] = stream.Process(windows[1], sequence.calibration.camera);
  }
  ASSERT_TRUE(second[1].continued);
  const EstimatorResult &a = second[0].result, &b = second[1].result;
  ASSERT_EQ(a.latent.size(), b.latent.size());
  for (size_t t = 0; t < a.latent.size(); ++t) {
    EXPECT_TRUE(SameBits(a.latent[t], b.latent[t])) << "latent " << t;
    EXPECT_TRUE(SameBits(a.depth[t], b.depth[t])) << "depth " << t;
    EXPECT_TRUE(SamePose(a.T_world_cam[t], b.T_world_cam[t])) << "pose " << t;
  }
  ASSERT_EQ(a.energies.size(), b.energies.size());
  for (size_t i = 0; i < a.energies.size(); ++i) EXPECT_EQ(a.energies[i].total, b.energies[i].total) << i;
}

}  // namespace
}  // namespace deblur_sr_mvs
