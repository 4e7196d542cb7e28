#include "deblur_sr_mvs/core/evaluation/synthesizer.h"

#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <yaml-cpp/yaml.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

namespace deblur_sr_mvs {
namespace {

namespace fs = std::filesystem;

const std::string kDollsFolder = std::string(DSM_SOURCE_DIR) + "/data/middlebury/Dolls";

// Loaded once: every test reads the same bundled scene.
const StereoScene& Dolls() {
  static const StereoScene scene = LoadMiddleburyScene(kDollsFolder);
  return scene;
}
const SceneRenderer& DollsRenderer() {
  static const SceneRenderer renderer(Dolls());
  return renderer;
}

// A fresh folder per test, removed afterwards.
class TempFolder {
 public:
  explicit TempFolder(const std::string& tag) {
    const ::testing::TestInfo* info = ::testing::UnitTest::GetInstance()->current_test_info();
    path_ = fs::path(::testing::TempDir()) /
            ("dsm_synth_" + tag + "_" + info->name() + "_" + std::to_string(::getpid()));
    fs::remove_all(path_);
    fs::create_directories(path_);
  }
  ~TempFolder() {
    std::error_code error;
    fs::remove_all(path_, error);
  }
  std::string operator/(const std::string& name) const { return (path_ / name).string(); }
  std::string str() const { return path_.string(); }

 private:
  fs::path path_;
};

void ExpectInputError(const std::function<void()>& call, const std::string& part) {
  try {
    call();
    ADD_FAILURE() << "expected InputError containing '" << part << "'";
  } catch (const InputError& error) {
    const std::string message = error.what();
    EXPECT_EQ(message.find('\n'), std::string::npos) << "not one line: " << message;
    EXPECT_NE(message.find(part), std::string::npos) << "'" << message << "' lacks '" << part << "'";
  }
}

// PSNR (peak 255) of two 3-channel images over the mask's non-zero pixels.
double Psnr(const cv::Mat& a, const cv::Mat& b, const cv::Mat& mask) {
  cv::Mat a64, b64;
  a.convertTo(a64, CV_64FC3);
  b.convertTo(b64, CV_64FC3);
  double sum = 0.0;
  int count = 0;
  for (int y = 0; y < a.rows; ++y) {
    for (int x = 0; x < a.cols; ++x) {
      if (!mask.at<uint8_t>(y, x)) continue;
      const cv::Vec3d d = a64.at<cv::Vec3d>(y, x) - b64.at<cv::Vec3d>(y, x);
      sum += d.dot(d) / 3.0;
      ++count;
    }
  }
  EXPECT_GT(count, 0);
  return 10.0 * std::log10(255.0 * 255.0 / std::max(sum / count, 1e-12));
}

// Non-hole pixels inside a centred crop of 80 % of the image.
cv::Mat CentreMask(const RenderResult& render) {
  cv::Mat mask = cv::Mat::zeros(render.image.size(), CV_8UC1);
  const int mx = render.image.cols / 10, my = render.image.rows / 10;
  mask(cv::Rect(mx, my, render.image.cols - 2 * mx, render.image.rows - 2 * my)).setTo(255);
  mask.setTo(0, render.hole_mask);
  return mask;
}

// Rendering a view's own pose with its own camera must give back its image
// and its Middlebury depth: the points sit exactly on pixel centres.
void ExpectReproducesView(int view_index) {
  const SceneView& view = Dolls().views[view_index];
  const RenderResult render = DollsRenderer().Render(view.camera, view.T_world_cam);
  ASSERT_EQ(render.image.size(), view.image.size());
  EXPECT_LT(render.HoleFraction(), 0.01);
  const cv::Mat mask = CentreMask(render);
  EXPECT_GT(Psnr(render.image, view.image, mask), 35.0);
  int compared = 0, wrong = 0;
  for (int y = 0; y < mask.rows; ++y) {
    for (int x = 0; x < mask.cols; ++x) {
      const float known = view.depth.at<float>(y, x);
      if (!mask.at<uint8_t>(y, x) || known <= 0.0f) continue;
      ++compared;
      wrong += std::abs(render.depth.at<float>(y, x) - known) > 1e-3f * known;
    }
  }
  EXPECT_GT(compared, mask.total() / 2);
  EXPECT_LT(wrong, compared / 200) << wrong << " of " << compared << " depths differ";
}

TEST(SynthesizerSceneTest, LoadsDollsWithTheDocumentedCalibration) {
  const StereoScene& scene = Dolls();
  EXPECT_EQ(scene.dmin, 200);
  EXPECT_NEAR(scene.focal_px, 3740.0 / 3.0, 1e-9);
  for (const SceneView& view : scene.views) {
    EXPECT_EQ(view.image.size(), cv::Size(463, 370));
    EXPECT_EQ(view.image.type(), CV_8UC3);
    EXPECT_EQ(view.depth.type(), CV_32FC1);
  }
  EXPECT_NEAR(scene.views[0].camera.cx, 231.0, 1e-9);
  EXPECT_NEAR(scene.views[0].camera.cy, 184.5, 1e-9);
  EXPECT_NEAR(scene.views[1].camera.cx - scene.views[0].camera.cx, 200.0 / 3.0, 1e-9);
  EXPECT_NEAR(scene.views[1].T_world_cam.translation().x(), 0.160, 1e-12);
  // SOURCES.md: Dolls spans 1421-2863 mm.
  EXPECT_NEAR(scene.min_depth, 1.421, 0.002);
  EXPECT_NEAR(scene.max_depth, 2.863, 0.002);
  EXPECT_GT(scene.median_depth, scene.min_depth);
  EXPECT_LT(scene.median_depth, scene.max_depth);
  // Unknown disparity (~0.4 %) makes no point.
  EXPECT_GT(DollsRenderer().NumPoints(0), 0.99 * 463 * 370);
  EXPECT_LT(DollsRenderer().NumPoints(0), 463 * 370);
}

TEST(SynthesizerSceneTest, RejectsBrokenFolders) {
  TempFolder folder("scene");
  ExpectInputError([&] { LoadMiddleburyScene(folder / "nothing"); }, "nothing");
  for (const char* name : {"view1.png", "view5.png", "disp1.png", "disp5.png", "dmin.txt"}) {
    fs::copy_file(kDollsFolder + "/" + name, folder / name);
  }
  // CRLF and spaces around dmin are fine.
  std::ofstream(folder / "dmin.txt", std::ios::binary) << " 200\r\n";
  EXPECT_EQ(LoadMiddleburyScene(folder.str()).dmin, 200);
  for (const char* bad : {"", "abc", "200x", "2 00", "-5"}) {
    std::ofstream(folder / "dmin.txt", std::ios::binary) << bad;
    ExpectInputError([&] { LoadMiddleburyScene(folder.str()); }, "dmin.txt");
  }
  std::ofstream(folder / "dmin.txt", std::ios::binary) << "200\n";
  const cv::Mat disparity = cv::imread(folder / "disp5.png", cv::IMREAD_UNCHANGED);
  cv::imwrite(folder / "disp5.png", disparity(cv::Rect(0, 0, 100, 100)));
  ExpectInputError([&] { LoadMiddleburyScene(folder.str()); }, "disp5.png");
  fs::remove(folder / "disp5.png");
  ExpectInputError([&] { LoadMiddleburyScene(folder.str()); }, "disp5.png");
  std::ofstream(folder / "view1.png") << "not a png";
  ExpectInputError([&] { LoadMiddleburyScene(folder.str()); }, "view1.png");
}

TEST(SynthesizerRendererTest, View1PoseReproducesView1) {
  ExpectReproducesView(0);
}

TEST(SynthesizerRendererTest, View5PoseReproducesView5) {
  ExpectReproducesView(1);
}

// The real calibration check: view5's points alone, seen from view1, must
// land on view1's pixels with view1's depth and colours. A wrong principal
// point, baseline or depth formula moves them by many pixels.
TEST(SynthesizerRendererTest, View5PointsSeenFromView1MatchView1) {
  const SceneView& view1 = Dolls().views[0];
  RenderOptions options;
  options.only_view = 1;
  options.fill_holes = false;
  const RenderResult render = DollsRenderer().Render(view1.camera, view1.T_world_cam, options);
  const cv::Mat mask = CentreMask(render);
  std::vector<float> depth_errors;
  double colour_error = 0.0;
  for (int y = 0; y < mask.rows; ++y) {
    for (int x = 0; x < mask.cols; ++x) {
      const float known = view1.depth.at<float>(y, x);
      if (!mask.at<uint8_t>(y, x) || known <= 0.0f) continue;
      depth_errors.push_back(std::abs(render.depth.at<float>(y, x) - known) / known);
      const cv::Vec3f rendered = render.image.at<cv::Vec3f>(y, x);
      const cv::Vec3b original = view1.image.at<cv::Vec3b>(y, x);
      for (int c = 0; c < 3; ++c) colour_error += std::abs(rendered[c] - original[c]) / 3.0;
    }
  }
  ASSERT_GT(depth_errors.size(), mask.total() / 2);
  colour_error /= depth_errors.size();
  std::nth_element(depth_errors.begin(), depth_errors.begin() + depth_errors.size() / 2, depth_errors.end());
  EXPECT_LT(depth_errors[depth_errors.size() / 2], 0.01);
  EXPECT_LT(colour_error, 15.0);  // SOURCES.md: warping error 6.4 on Dolls
}

// The primary view is the one nearer to the camera; RenderOptions::
// primary_view fixes it (as the synthesizer does for a whole exposure): the
// nearer one gives the default render bit for bit, the other a different one.
TEST(SynthesizerRendererTest, PrimaryViewIsTheNearerOneUnlessFixed) {
  const StereoScene& scene = Dolls();
  const Eigen::Vector3d c0 = scene.views[0].T_world_cam.translation();
  const Eigen::Vector3d c1 = scene.views[1].T_world_cam.translation();
  const PinholeCamera& camera = scene.views[0].camera;
  for (const double fraction : {0.45, 0.55}) {  // just either side of the views' bisector
    const SE3 T_world_cam(Eigen::Matrix3d::Identity(), c0 + fraction * (c1 - c0));
    const int nearer = fraction < 0.5 ? 0 : 1;
    EXPECT_EQ(DollsRenderer().PrimaryView(T_world_cam), nearer);
    const RenderResult automatic = DollsRenderer().Render(camera, T_world_cam);
    RenderOptions options;
    options.primary_view = nearer;
    const RenderResult same = DollsRenderer().Render(camera, T_world_cam, options);
    options.primary_view = 1 - nearer;
    const RenderResult other = DollsRenderer().Render(camera, T_world_cam, options);
    EXPECT_EQ(cv::norm(automatic.image, same.image, cv::NORM_INF), 0.0);
    EXPECT_GT(cv::norm(automatic.image, other.image, cv::NORM_L1), 0.0);
  }
  // On the bisector (where the rotate path turns) view 0, whatever the
  // rounding of the two distances: every frame of such a path renders alike.
  for (const double along : {0.0, 0.3, -0.7}) {
    const Eigen::Vector3d on_bisector = 0.5 * (c0 + c1) + Eigen::Vector3d(0.0, along, 1.3 * along);
    EXPECT_EQ(DollsRenderer().PrimaryView(SE3(Eigen::Matrix3d::Identity(), on_bisector)), 0) << along;
  }
}

// Soft splatting resamples smoothly: a sub-pixel camera shift changes the
// image gradually, not by whole-pixel jumps, and leaves no cracks.
TEST(SynthesizerRendererTest, SubPixelShiftIsSmoothAndCrackFree) {
  const StereoScene& scene = Dolls();
  const PinholeCamera& camera = scene.views[0].camera;
  // Shift of a quarter pixel at the median depth.
  const double shift_m = 0.25 * scene.median_depth / scene.focal_px;
  const RenderResult a = DollsRenderer().Render(camera, SE3());
  const RenderResult b =
      DollsRenderer().Render(camera, SE3(Eigen::Matrix3d::Identity(), Eigen::Vector3d(shift_m, 0.0, 0.0)));
  const RenderResult c = DollsRenderer().Render(
      camera, SE3(Eigen::Matrix3d::Identity(), Eigen::Vector3d(4.0 * shift_m, 0.0, 0.0)));
  EXPECT_LT(b.HoleFraction(), 0.01);
  const cv::Mat mask = CentreMask(a);
  const double psnr_quarter = Psnr(a.image, b.image, mask);
  const double psnr_pixel = Psnr(a.image, c.image, mask);
  EXPECT_GT(psnr_quarter, psnr_pixel + 3.0);
  EXPECT_GT(psnr_quarter, 28.0);
}

TEST(SynthesizerPathTest, PathsAreGeodesicsThroughTheMidpoint) {
  const StereoScene& scene = Dolls();
  for (CameraPathType type : {CameraPathType::kLateral, CameraPathType::kArc, CameraPathType::kForward}) {
    SCOPED_TRACE(CameraPathName(type));
    EXPECT_EQ(ParseCameraPathType(CameraPathName(type)), type);
    CameraPath path = MakeCameraPath(type, scene, 0.2, 2.0);
    path.speed = 0.5;
    const SE3 mid = path.PoseAt(0.2);
    EXPECT_NEAR((mid.translation() - Eigen::Vector3d(0.08, 0.0, 0.0)).norm(), 0.0, 1e-12);
    EXPECT_NEAR((mid.rotation() - Eigen::Matrix3d::Identity()).norm(), 0.0, 1e-12);
    // Unit twists move the centre at `speed` m/s, from view1 towards view5.
    const double dt = 1e-4;
    const Eigen::Vector3d velocity =
        (path.PoseAt(0.2 + dt).translation() - path.PoseAt(0.2 - dt).translation()) / (2 * dt);
    EXPECT_NEAR(velocity.norm(), 0.5, 1e-6);
    EXPECT_GT(velocity.x(), 0.0);
    // Constant velocity: eq:interpolatingP between two frames is the path.
    const SE3 s = path.PoseAt(0.1), t = path.PoseAt(0.3);
    const SE3 interpolated = InterpolatePose(s, t, 0.3);
    const SE3 expected = path.PoseAt(0.16);
    EXPECT_NEAR((interpolated.translation() - expected.translation()).norm(), 0.0, 1e-9);
    EXPECT_NEAR((interpolated.rotation() - expected.rotation()).norm(), 0.0, 1e-9);
  }
  // The arc keeps its distance to the fixation point and looks at it.
  CameraPath arc = MakeCameraPath(CameraPathType::kArc, scene, 0.0, 2.0);
  arc.speed = 1.0;
  const double radius = 2.0 * scene.median_depth;
  for (double t : {-0.3, -0.1, 0.2, 0.4}) {
    const SE3 pose = arc.PoseAt(t);
    const Eigen::Vector3d to_fixation = arc.fixation_point - pose.translation();
    EXPECT_NEAR(to_fixation.norm(), radius, 1e-9);
    EXPECT_NEAR(to_fixation.normalized().dot(pose.rotation().col(2)), 1.0, 1e-9);
    EXPECT_NEAR(pose.translation().y(), 0.0, 1e-12);  // horizontal circle
  }
  // Forward moves mostly along the optical axis.
  CameraPath forward = MakeCameraPath(CameraPathType::kForward, scene, 0.0, 2.0);
  forward.speed = 1.0;
  const Eigen::Vector3d step = forward.PoseAt(1.0).translation() - forward.PoseAt(0.0).translation();
  EXPECT_GT(step.z(), 3.0 * step.x());
  EXPECT_GT(step.x(), 0.0);
  ExpectInputError([] { ParseCameraPathType("zigzag"); }, "zigzag");
}

TEST(SynthesizerPathTest, ImageMotionOfAFrontoParallelPlane) {
  const PinholeCamera camera(40, 30, 500.0, 500.0, 19.5, 14.5);
  const cv::Mat depth(30, 40, CV_32FC1, cv::Scalar(2.0));
  // 4 cm sideways at 2 m: 500 * 0.04 / 2 = 10 px everywhere.
  const MotionStats stats = MeasureImageMotion(
      camera, depth, SE3(), SE3(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0.04, 0.0, 0.0)));
  EXPECT_EQ(stats.num_pixels, 1200);
  EXPECT_NEAR(stats.min_px, 10.0, 1e-4);
  EXPECT_NEAR(stats.median_px, 10.0, 1e-4);
  EXPECT_NEAR(stats.max_px, 10.0, 1e-4);
}

TEST(SynthesizerOptionsTest, CheckRejectsBadOptions) {
  SynthesisOptions good;
  EXPECT_NO_THROW(good.Check());
  const std::vector<std::pair<std::string, std::function<void(SynthesisOptions*)>>> cases = {
      {"--frames", [](SynthesisOptions* o) { o->num_frames = 1; }},
      {"--scale", [](SynthesisOptions* o) { o->scale = 0; }},
      {"--exposure-ratio", [](SynthesisOptions* o) { o->exposure_ratio = 0.0; }},
      {"--exposure-ratio", [](SynthesisOptions* o) { o->exposure_ratio = 1.5; }},
      {"--exposure-ratio", [](SynthesisOptions* o) { o->exposure_ratio = std::nan(""); }},
      {"--noise", [](SynthesisOptions* o) { o->noise_sigma = -1.0; }},
      {"--blur-px", [](SynthesisOptions* o) { o->blur_px = 0.0; }},
      {"--subframes", [](SynthesisOptions* o) { o->subframes = 50; }},
      {"--fps", [](SynthesisOptions* o) { o->fps = 0.0; }},
      {"--hr-width",
       [](SynthesisOptions* o) {
         o->hr_width = 101;
         o->hr_height = 100;
       }},
      {"--hr-width", [](SynthesisOptions* o) { o->hr_width = 100; }},
  };
  for (const auto& [flag, spoil] : cases) {
    SynthesisOptions options;
    spoil(&options);
    ExpectInputError([&] { options.Check(); }, flag);
  }
}

// A small sequence shared by the synthesis tests (3 frames, 60 sub-frames).
struct TinySequence {
  SynthesisOptions options;
  SynthesisResult result;
};
const TinySequence& Tiny() {
  static const TinySequence tiny = [] {
    TinySequence t;
    t.options.num_frames = 3;
    t.options.subframes = 60;
    t.result = SynthesizeSequence(Dolls(), t.options);
    return t;
  }();
  return tiny;
}

TEST(SynthesizerSequenceTest, SynthesisYamlReadsBackWithAwkwardScenePath) {
  StereoScene scene = Dolls();
  scene.folder = "scenes/with \"quote\" and \\ backslash: #1";
  TempFolder folder("yaml");
  const std::string path = folder / "gt/synthesis.yaml";
  WriteSynthesisYaml(path, scene, Tiny().options, Tiny().result);
  const YAML::Node root = YAML::LoadFile(path);
  EXPECT_EQ(root["scene"].as<std::string>(), scene.folder);
  EXPECT_EQ(root["options"]["frames"].as<int>(), 3);
  EXPECT_EQ(root["options"]["path"].as<std::string>(), "lateral");
  EXPECT_EQ(root["hr_camera"]["width"].as<int>(), Tiny().result.hr_camera.width);
  EXPECT_EQ(root["path"]["speed_capped"].as<bool>(), Tiny().result.speed_capped);
  EXPECT_EQ(root["path"]["T_world_mid"].size(), 3u);
  ASSERT_EQ(root["frames"].size(), 3u);
  EXPECT_EQ(root["frames"][2]["index"].as<int>(), 2);
  // Ten significant digits, as before.
  EXPECT_NEAR(root["frames"][1]["stamp"].as<double>(), 2.0 / 30.0, 1e-10);
}

TEST(SynthesizerSequenceTest, SizesCamerasStampsAndExposures) {
  const SynthesisOptions& options = Tiny().options;
  const SynthesisResult& result = Tiny().result;
  const Sequence& sequence = result.sequence;
  const PinholeCamera& hr = result.hr_camera;
  const PinholeCamera& lr = sequence.calibration.camera;
  // HR: the scene's focal length, a crop of the scene size divisible by the
  // scale, centred on what both views see: the principal point lies halfway
  // between view1's (image centre) and view5's (shifted by dmin/3 = 200/3).
  EXPECT_NEAR(hr.fx, 3740.0 / 3.0, 1e-9);
  EXPECT_NEAR(hr.fy, 3740.0 / 3.0, 1e-9);
  EXPECT_NEAR(hr.cx, (hr.width - 1) / 2.0 + 200.0 / 6.0, 1e-9);
  EXPECT_NEAR(hr.cy, (hr.height - 1) / 2.0, 1e-9);
  EXPECT_LE(hr.width, 463);
  EXPECT_LE(hr.height, 370);
  EXPECT_GE(hr.width, 463 / 2);
  EXPECT_EQ(hr.width % 2, 0);
  EXPECT_EQ(hr.height % 2, 0);
  // LR by docs/file_formats.md#scaling-rule: fx' = fx / s, cx' = (cx - (s - 1) / 2) / s.
  EXPECT_EQ(lr.width, hr.width / 2);
  EXPECT_EQ(lr.height, hr.height / 2);
  EXPECT_NEAR(lr.fx, hr.fx / 2.0, 1e-9);
  EXPECT_NEAR(lr.cx, (hr.cx - 0.5) / 2.0, 1e-9);
  EXPECT_NEAR(lr.cy, (hr.cy - 0.5) / 2.0, 1e-9);
  ASSERT_TRUE(sequence.ground_truth.has_value());
  const SequenceGroundTruth& gt = *sequence.ground_truth;
  EXPECT_NEAR(gt.calibration.camera.fx, hr.fx, 1e-9);
  EXPECT_EQ(gt.calibration.camera.width, hr.width);

  ASSERT_EQ(sequence.frames.size(), 3u);
  ASSERT_EQ(sequence.images.size(), 3u);
  ASSERT_EQ(gt.latent.size(), 3u);
  ASSERT_EQ(gt.depth.size(), 3u);
  ASSERT_EQ(gt.poses.size(), 3u);
  for (int i = 0; i < 3; ++i) {
    SCOPED_TRACE(i);
    EXPECT_EQ(sequence.frames[i].index, i);
    EXPECT_NEAR(sequence.frames[i].stamp, (i + 1) / 30.0, 1e-12);
    EXPECT_NEAR(sequence.frames[i].exposure, 0.8 / 30.0, 1e-12);
    EXPECT_EQ(sequence.images[i].type(), CV_8UC3);
    EXPECT_EQ(sequence.images[i].size(), cv::Size(lr.width, lr.height));
    EXPECT_EQ(gt.latent[i].type(), CV_8UC3);
    EXPECT_EQ(gt.latent[i].size(), cv::Size(hr.width, hr.height));
    EXPECT_EQ(gt.depth[i].type(), CV_32FC1);
    EXPECT_EQ(gt.depth[i].size(), cv::Size(hr.width, hr.height));
    EXPECT_NEAR(gt.poses[i].stamp, sequence.frames[i].stamp, 1e-12);
    const SE3 expected = result.path.PoseAt(sequence.frames[i].stamp);
    EXPECT_NEAR((gt.poses[i].T_world_cam.translation() - expected.translation()).norm(), 0.0, 1e-12);
  }
  // The path passes the midpoint halfway through [t_o(0), t_c(last)].
  EXPECT_NEAR(result.path.t_mid, 0.5 * ((1 - 0.8) / 30.0 + 3 / 30.0), 1e-12);
  EXPECT_EQ(options.path, CameraPathType::kLateral);
}

TEST(SynthesizerSequenceTest, DefaultBlurIsSevereAndGroundTruthIsPlausible) {
  const SynthesisResult& result = Tiny().result;
  EXPECT_NEAR(result.achieved_blur_px, 14.0, 0.5);
  EXPECT_FALSE(result.speed_capped);
  ASSERT_EQ(result.frame_stats.size(), 3u);
  for (std::size_t i = 0; i < result.frame_stats.size(); ++i) {
    SCOPED_TRACE(i);
    const FrameSynthesisStats& stats = result.frame_stats[i];
    EXPECT_GE(stats.blur.median_px, 8.0);
    EXPECT_LE(stats.blur.median_px, 20.0);
    EXPECT_LT(stats.hole_fraction_latent, 0.02);
    EXPECT_LT(stats.hole_fraction_max, 0.02);
    double min_depth, max_depth;
    cv::minMaxLoc(result.sequence.ground_truth->depth[i], &min_depth, &max_depth);
    EXPECT_GT(min_depth, 1.40);  // Dolls: 1.42-2.87 m, every pixel filled
    EXPECT_LT(max_depth, 2.90);
  }
  // Lateral blur smears horizontally: the blurred frame keeps much less of
  // the sharp image's horizontal detail than of its vertical detail.
  const cv::Mat& blurred8 = result.sequence.images[1];
  cv::Mat sharp_lr, blurred, sharp;
  cv::resize(result.sequence.ground_truth->latent[1], sharp_lr, blurred8.size(), 0, 0, cv::INTER_AREA);
  blurred8.convertTo(blurred, CV_32FC3);
  sharp_lr.convertTo(sharp, CV_32FC3);
  auto detail = [](const cv::Mat& image, int dx, int dy) {
    cv::Mat gradient;
    cv::Sobel(image, gradient, CV_32F, dx, dy);
    return cv::norm(gradient, cv::NORM_L2SQR);  // energy: blur keeps L1 of monotone edges
  };
  const double horizontal_kept = detail(blurred, 1, 0) / detail(sharp, 1, 0);
  const double vertical_kept = detail(blurred, 0, 1) / detail(sharp, 0, 1);
  EXPECT_LT(horizontal_kept, 0.4) << "vertical " << vertical_kept;
  EXPECT_LT(horizontal_kept, 0.6 * vertical_kept) << "vertical " << vertical_kept;
}

TEST(SynthesizerSequenceTest, NoiseIsDeterministicPerSeed) {
  SynthesisOptions options;
  options.num_frames = 2;
  options.subframes = 51;
  options.noise_sigma = 3.0;
  options.seed = 7;
  const SynthesisResult a = SynthesizeSequence(Dolls(), options);
  const SynthesisResult b = SynthesizeSequence(Dolls(), options);
  options.seed = 8;
  const SynthesisResult c = SynthesizeSequence(Dolls(), options);
  options.noise_sigma = 0.0;
  const SynthesisResult clean = SynthesizeSequence(Dolls(), options);
  for (int i = 0; i < 2; ++i) {
    EXPECT_EQ(cv::norm(a.sequence.images[i], b.sequence.images[i], cv::NORM_INF), 0.0);
    EXPECT_GT(cv::norm(a.sequence.images[i], c.sequence.images[i], cv::NORM_L1), 0.0);
    // The noise has the requested standard deviation (plus rounding).
    cv::Mat difference;
    cv::subtract(a.sequence.images[i], clean.sequence.images[i], difference, cv::noArray(), CV_32F);
    cv::Scalar mean, stddev;
    cv::meanStdDev(difference.reshape(1), mean, stddev);
    EXPECT_NEAR(stddev[0], 3.0, 0.3);
    EXPECT_NEAR(mean[0], 0.0, 0.2);
  }
}

// ------------------------------------------- rotate, handheld, gain, shutter

// A small, fast sequence: 64x48 HR (32x24 LR), few sub-frames.
SynthesisOptions SmallOptions(CameraPathType path, int frames) {
  SynthesisOptions options;
  options.path = path;
  options.num_frames = frames;
  options.subframes = 51;
  options.hr_width = 64;
  options.hr_height = 48;
  options.blur_px = 8.0;
  return options;
}

double RotationAngle(const SE3& a, const SE3& b) {
  return Eigen::AngleAxisd(a.rotation().transpose() * b.rotation()).angle();
}

TEST(SynthesizerPathTest, NewPathNamesRoundTrip) {
  for (CameraPathType type : {CameraPathType::kHandheld, CameraPathType::kRotate}) {
    EXPECT_EQ(ParseCameraPathType(CameraPathName(type)), type);
  }
  EXPECT_EQ(CameraPathName(CameraPathType::kHandheld), "handheld");
  EXPECT_EQ(CameraPathName(CameraPathType::kRotate), "rotate");
}

TEST(SynthesizerPathTest, RotateTurnsAboutTheCameraCentre) {
  CameraPath path = MakeCameraPath(CameraPathType::kRotate, Dolls(), 0.2, 2.0);
  path.speed = 0.5;  // rad/s
  const Eigen::Vector3d centre(0.08, 0.0, 0.0);
  for (double t : {-0.5, 0.0, 0.13, 0.2, 0.6}) {
    EXPECT_NEAR((path.PoseAt(t).translation() - centre).norm(), 0.0, 1e-12) << t;
  }
  EXPECT_NEAR(RotationAngle(path.PoseAt(0.1), path.PoseAt(0.3)), 0.1, 1e-9);
  // Mostly yaw (about y) with some pitch (about x), no roll.
  const Eigen::AngleAxisd turn(path.PoseAt(0.2).rotation().transpose() * path.PoseAt(0.4).rotation());
  EXPECT_GT(std::abs(turn.axis().y()), 3.0 * std::abs(turn.axis().x()));
  EXPECT_GT(std::abs(turn.axis().x()), 0.1);
  EXPECT_NEAR(turn.axis().z(), 0.0, 1e-9);
}

TEST(SynthesizerSequenceTest, RotateHasConstantPositionAndTheRequestedBlur) {
  const SynthesisOptions options = SmallOptions(CameraPathType::kRotate, 3);
  const SynthesisResult result = SynthesizeSequence(Dolls(), options);
  const std::vector<StampedPose>& poses = result.sequence.ground_truth->poses;
  ASSERT_EQ(poses.size(), 3u);
  for (const StampedPose& pose : poses) {
    EXPECT_NEAR((pose.T_world_cam.translation() - poses[0].T_world_cam.translation()).norm(), 0.0, 1e-12);
  }
  EXPECT_GT(RotationAngle(poses[0].T_world_cam, poses[2].T_world_cam), 1e-3);
  EXPECT_NEAR(result.achieved_blur_px, options.blur_px, 0.02 * options.blur_px);
  for (const FrameSynthesisStats& stats : result.frame_stats) {
    EXPECT_NEAR(stats.blur.median_px, options.blur_px, 0.1 * options.blur_px);
  }
  // gt depth stays the scene's depth: the rotation does not move the centre.
  double min_depth = 0.0, max_depth = 0.0;
  cv::minMaxLoc(result.sequence.ground_truth->depth[1], &min_depth, &max_depth);
  EXPECT_GE(min_depth, 0.9 * Dolls().min_depth);
  EXPECT_LE(max_depth, 1.1 * Dolls().max_depth);
}

// Speeds of the camera centre at n times over [t0, t1] (central differences).
std::vector<double> CentreSpeeds(const CameraPath& path, double t0, double t1, int n) {
  std::vector<double> speeds;
  const double dt = 1e-5;
  for (int k = 0; k < n; ++k) {
    const double t = t0 + (t1 - t0) * k / (n - 1);
    speeds.push_back((path.PoseAt(t + dt).translation() - path.PoseAt(t - dt).translation()).norm() /
                     (2 * dt));
  }
  return speeds;
}

TEST(SynthesizerPathTest, HandheldIsSeededSmoothAndVariesItsVelocity) {
  const double duration = 0.3;
  CameraPath a = MakeCameraPath(CameraPathType::kHandheld, Dolls(), 0.2, 2.0, duration, 1);
  CameraPath b = MakeCameraPath(CameraPathType::kHandheld, Dolls(), 0.2, 2.0, duration, 1);
  CameraPath c = MakeCameraPath(CameraPathType::kHandheld, Dolls(), 0.2, 2.0, duration, 2);
  a.speed = b.speed = c.speed = 0.5;
  for (double t : {0.05, 0.2, 0.35}) {
    EXPECT_EQ(a.PoseAt(t).Matrix(), b.PoseAt(t).Matrix());
    EXPECT_GT((a.PoseAt(t).Matrix() - c.PoseAt(t).Matrix()).norm(), 1e-4);
  }
  // Passes the midpoint at t_mid, then drifts along the baseline with shake.
  EXPECT_NEAR((a.PoseAt(0.2).translation() - Eigen::Vector3d(0.08, 0.0, 0.0)).norm(), 0.0, 0.05);
  const std::vector<double> speeds = CentreSpeeds(a, 0.05, 0.35, 31);
  const auto [slowest, fastest] = std::minmax_element(speeds.begin(), speeds.end());
  EXPECT_GT(*fastest, 1.3 * *slowest) << "velocity should not be constant";
  EXPECT_GT(*slowest, 0.0);
  // Rotation jitter: the orientation changes, at a varying rate, and smoothly
  // (no jump between close times).
  std::vector<double> turn_rates;
  for (int k = 0; k < 30; ++k) {
    const double t = 0.05 + 0.01 * k;
    turn_rates.push_back(RotationAngle(a.PoseAt(t), a.PoseAt(t + 0.01)) / 0.01);
  }
  const auto [slow_turn, fast_turn] = std::minmax_element(turn_rates.begin(), turn_rates.end());
  EXPECT_GT(*fast_turn, 1e-3);
  EXPECT_GT(*fast_turn, 1.3 * *slow_turn);
  EXPECT_LT(RotationAngle(a.PoseAt(0.2), a.PoseAt(0.2001)), 1e-4);
}

TEST(SynthesizerSequenceTest, HandheldIsDeterministicPerSeedAndHitsTheBlur) {
  SynthesisOptions options = SmallOptions(CameraPathType::kHandheld, 3);
  options.seed = 11;
  const SynthesisResult a = SynthesizeSequence(Dolls(), options);
  const SynthesisResult b = SynthesizeSequence(Dolls(), options);
  options.seed = 12;
  const SynthesisResult c = SynthesizeSequence(Dolls(), options);
  EXPECT_NEAR(a.achieved_blur_px, options.blur_px, 0.02 * options.blur_px);
  EXPECT_NEAR(c.achieved_blur_px, options.blur_px, 0.02 * options.blur_px);
  // Its speed varies, so the blur is calibrated as the median over the frames.
  std::vector<double> blurs;
  for (const FrameSynthesisStats& stats : a.frame_stats) blurs.push_back(stats.blur.median_px);
  std::sort(blurs.begin(), blurs.end());
  EXPECT_NEAR(blurs[1], options.blur_px, 0.05 * options.blur_px);
  for (int i = 0; i < 3; ++i) {
    EXPECT_EQ(cv::norm(a.sequence.images[i], b.sequence.images[i], cv::NORM_INF), 0.0);
    EXPECT_EQ(cv::norm(a.sequence.ground_truth->latent[i], b.sequence.ground_truth->latent[i], cv::NORM_INF),
              0.0);
    EXPECT_EQ(a.sequence.ground_truth->poses[i].T_world_cam.Matrix(),
              b.sequence.ground_truth->poses[i].T_world_cam.Matrix());
    EXPECT_GT(cv::norm(a.sequence.images[i], c.sequence.images[i], cv::NORM_L1), 0.0);
    // The scene stays in view: few pixels that no view covers.
    EXPECT_LT(a.frame_stats[i].hole_fraction_max, 0.05);
  }
  // Non-constant velocity over the rendered span (first open to last close).
  for (const SynthesisResult* result : {&a, &c}) {
    const double t0 = result->sequence.frames.front().stamp - result->sequence.frames.front().exposure;
    const std::vector<double> speeds =
        CentreSpeeds(result->path, t0, result->sequence.frames.back().stamp, 21);
    const auto [slowest, fastest] = std::minmax_element(speeds.begin(), speeds.end());
    EXPECT_GT(*fastest, 1.2 * *slowest);
  }
}

// Mean of the pixels of `image` (any 8-bit type) where `mask` is set.
double MaskedMean(const cv::Mat& image, const cv::Mat& mask) {
  return cv::mean(image.reshape(1, image.rows), mask.reshape(1, mask.rows))[0];
}

TEST(SynthesizerSequenceTest, GainJitterScalesFrameAndLatent) {
  SynthesisOptions options = SmallOptions(CameraPathType::kLateral, 4);
  options.seed = 4;
  const SynthesisResult plain = SynthesizeSequence(Dolls(), options);
  options.gain_jitter = 0.3;
  const SynthesisResult jittered = SynthesizeSequence(Dolls(), options);
  std::vector<double> gains;
  for (int i = 0; i < 4; ++i) {
    const double gain = jittered.frame_stats[i].gain;
    EXPECT_EQ(plain.frame_stats[i].gain, 1.0);
    EXPECT_GE(gain, 0.7);
    EXPECT_LE(gain, 1.3);
    gains.push_back(gain);
    const cv::Mat& frame0 = plain.sequence.images[i];
    const cv::Mat& latent0 = plain.sequence.ground_truth->latent[i];
    // Away from the 8-bit clamp, the ratio of means is the gain (rounding aside).
    const cv::Mat frame_mask = (frame0 * gain < 250.0) & (frame0 > 20);
    const cv::Mat latent_mask = (latent0 * gain < 250.0) & (latent0 > 20);
    EXPECT_NEAR(MaskedMean(jittered.sequence.images[i], frame_mask) / MaskedMean(frame0, frame_mask), gain,
                0.01);
    EXPECT_NEAR(
        MaskedMean(jittered.sequence.ground_truth->latent[i], latent_mask) / MaskedMean(latent0, latent_mask),
        gain, 0.01);
    // Depth and poses do not change.
    EXPECT_EQ(cv::norm(plain.sequence.ground_truth->depth[i], jittered.sequence.ground_truth->depth[i],
                       cv::NORM_INF),
              0.0);
  }
  EXPECT_GT(*std::max_element(gains.begin(), gains.end()) - *std::min_element(gains.begin(), gains.end()),
            0.01);
  // The gains are recorded per frame in gt/synthesis.yaml.
  TempFolder folder("gain");
  WriteSynthesisYaml(folder / "synthesis.yaml", Dolls(), options, jittered);
  const YAML::Node root = YAML::LoadFile(folder / "synthesis.yaml");
  EXPECT_EQ(root["options"]["gain_jitter"].as<double>(), 0.3);
  for (int i = 0; i < 4; ++i) EXPECT_NEAR(root["frames"][i]["gain"].as<double>(), gains[i], 1e-9);
}

TEST(SynthesizerSequenceTest, ReadoutRatioZeroIsTheGlobalShutter) {
  const SynthesisOptions options = SmallOptions(CameraPathType::kLateral, 2);
  SynthesisOptions zero = options;
  zero.readout_ratio = 0.0;
  zero.gain_jitter = 0.0;
  const SynthesisResult a = SynthesizeSequence(Dolls(), options);
  const SynthesisResult b = SynthesizeSequence(Dolls(), zero);
  EXPECT_EQ(b.sequence.readout_time, 0.0);
  for (int i = 0; i < 2; ++i) {
    EXPECT_EQ(cv::norm(a.sequence.images[i], b.sequence.images[i], cv::NORM_INF), 0.0);
    EXPECT_EQ(cv::norm(a.sequence.ground_truth->latent[i], b.sequence.ground_truth->latent[i], cv::NORM_INF),
              0.0);
  }
  TempFolder folder("global");
  WriteSequence(folder.str(), b.sequence);
  EXPECT_FALSE(fs::exists(folder / "sensor.yaml"));
}

TEST(SynthesizerSequenceTest, RollingShutterDelaysLowerRows) {
  const SynthesisOptions global = SmallOptions(CameraPathType::kLateral, 2);
  SynthesisOptions rolling = global;
  rolling.readout_ratio = 0.8;
  const SynthesisResult g = SynthesizeSequence(Dolls(), global);
  const SynthesisResult r = SynthesizeSequence(Dolls(), rolling);
  EXPECT_DOUBLE_EQ(r.sequence.readout_time, 0.8 / 30.0);
  const int rows = r.sequence.images[0].rows;  // 24 LR rows
  for (int i = 0; i < 2; ++i) {
    SCOPED_TRACE(i);
    const cv::Mat& gi = g.sequence.images[i];
    const cv::Mat& ri = r.sequence.images[i];
    // Row 0 is exposed over the global shutter's window, at the same sub-frame
    // times: equal up to the float summation order (at most 1 gray level).
    EXPECT_LE(cv::norm(gi.row(0), ri.row(0), cv::NORM_INF), 1.0);
    // The bottom rows are exposed ~0.77 frame intervals later: ~10 px of
    // lateral motion further on.
    const double bottom = cv::norm(gi.rowRange(rows - 3, rows), ri.rowRange(rows - 3, rows), cv::NORM_L1) /
                          (3.0 * gi.cols * gi.channels());
    EXPECT_GT(bottom, 3.0);
    // gt/ is the global-shutter sharp state at the stamp, unchanged.
    EXPECT_EQ(cv::norm(g.sequence.ground_truth->latent[i], r.sequence.ground_truth->latent[i], cv::NORM_INF),
              0.0);
    EXPECT_EQ(cv::norm(g.sequence.ground_truth->depth[i], r.sequence.ground_truth->depth[i], cv::NORM_INF),
              0.0);
    EXPECT_EQ(g.sequence.ground_truth->poses[i].T_world_cam.Matrix(),
              r.sequence.ground_truth->poses[i].T_world_cam.Matrix());
    EXPECT_EQ(g.sequence.frames[i].stamp, r.sequence.frames[i].stamp);
  }
  // sensor.yaml round-trips through ReadSequence.
  TempFolder folder("rolling");
  WriteSequence(folder.str(), r.sequence);
  ASSERT_TRUE(fs::exists(folder / "sensor.yaml"));
  EXPECT_EQ(ReadSequence(folder.str(), true).readout_time, r.sequence.readout_time);
}

TEST(SynthesizerOptionsTest, CheckRejectsBadGainAndReadout) {
  const std::vector<std::pair<std::string, std::function<void(SynthesisOptions*)>>> cases = {
      {"--gain-jitter", [](SynthesisOptions* o) { o->gain_jitter = -0.1; }},
      {"--gain-jitter", [](SynthesisOptions* o) { o->gain_jitter = 0.6; }},
      {"--gain-jitter", [](SynthesisOptions* o) { o->gain_jitter = std::nan(""); }},
      {"--readout-ratio", [](SynthesisOptions* o) { o->readout_ratio = -0.5; }},
      {"--readout-ratio", [](SynthesisOptions* o) { o->readout_ratio = 1.01; }},
  };
  for (const auto& [flag, spoil] : cases) {
    SynthesisOptions options;
    spoil(&options);
    ExpectInputError([&] { options.Check(); }, flag);
  }
  SynthesisOptions edge;
  edge.gain_jitter = 0.5;
  edge.readout_ratio = 1.0;
  EXPECT_NO_THROW(edge.Check());
}

// Exit status of a shell command, -1 when it did not exit normally.
int ExitCode(const std::string& command) {
  const int status = std::system((command + " >/dev/null 2>&1").c_str());
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

TEST(SynthesizerToolTest, BadInputExitsWithCode2) {
  const std::string tool = std::string(DSM_TOOL_DIR) + "/synthesize_sequence";
  TempFolder folder("tool");
  const std::string out = " --output " + (folder / "seq");
  const std::string scene = " --scene " + kDollsFolder;
  EXPECT_EQ(ExitCode(tool + " --help"), 0);
  EXPECT_EQ(ExitCode(tool + scene + out + " --bogus 1"), 2);
  EXPECT_EQ(ExitCode(tool + scene + out + " --frames"), 2);
  EXPECT_EQ(ExitCode(tool + scene + out + " --frames ten"), 2);
  EXPECT_EQ(ExitCode(tool + scene + out + " --exposure-ratio 1.5"), 2);
  EXPECT_EQ(ExitCode(tool + scene + out + " --path zigzag"), 2);
  EXPECT_EQ(ExitCode(tool + scene + out + " --seed -3"), 2);
  EXPECT_EQ(ExitCode(tool + out), 2);
  EXPECT_EQ(ExitCode(tool + " --scene " + (folder / "missing") + out), 2);
  EXPECT_FALSE(fs::exists(folder / "seq"));
}

TEST(SynthesizerToolTest, WritesAReadableSequence) {
  const std::string tool = std::string(DSM_TOOL_DIR) + "/synthesize_sequence";
  TempFolder folder("tool");
  const std::string seq = folder / "seq";
  ASSERT_EQ(ExitCode(tool + " --scene " + kDollsFolder + " --output " + seq +
                     " --frames 2 --subframes 51 --path arc --scale 2 --noise 1 --seed 3"),
            0);
  const Sequence sequence = ReadSequence(seq, true);
  ASSERT_EQ(sequence.frames.size(), 2u);
  ASSERT_TRUE(sequence.ground_truth.has_value());
  EXPECT_EQ(sequence.ground_truth->calibration.camera.width, 2 * sequence.calibration.camera.width);
  EXPECT_EQ(sequence.images[0].type(), CV_8UC3);
  EXPECT_TRUE(fs::exists(seq + "/gt/synthesis.yaml"));
}

}  // namespace
}  // namespace deblur_sr_mvs
