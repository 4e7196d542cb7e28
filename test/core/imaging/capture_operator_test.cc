// Properties of the capture operator Psi_t (eq:blurOperator) and of the
// visibility sets (eq:occUpdate).
#include "deblur_sr_mvs/core/imaging/capture_operator.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <functional>
#include <limits>
#include <optional>
#include <random>
#include <string>

#include <opencv2/imgproc.hpp>

#include <gtest/gtest.h>

#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/geometry/visibility.h"

namespace deblur_sr_mvs {
namespace {

// `call` throws InputError with exactly `message`.
void ExpectInputError(const std::function<void()>& call, const std::string& message) {
  try {
    call();
    ADD_FAILURE() << "expected InputError: " << message;
  } catch (const InputError& error) {
    EXPECT_EQ(std::string(error.what()), message);
  }
}

SE3 Translation(double x, double y, double z) {
  return SE3(Eigen::Matrix3d::Identity(), Eigen::Vector3d(x, y, z));
}

// A bumpy scene in front of the camera with a depth edge, so reprojection,
// z-buffering and occlusion all take part.
cv::Mat SceneDepth(int width, int height) {
  cv::Mat depth(height, width, CV_32FC1);
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      float d = 2.0f + 0.3f * std::sin(0.11f * x) * std::cos(0.07f * y);
      if (x > width / 3 && x < width / 2 && y > height / 4 && y < height / 2) d = 1.2f;
      depth.at<float>(y, x) = d;
    }
  }
  return depth;
}

CaptureGeometry MovingGeometry(int width, int height) {
  CaptureGeometry geometry;
  geometry.camera_hr =
      PinholeCamera(width, height, 0.9 * width, 0.9 * width, 0.5 * width - 0.3, 0.5 * height + 0.2);
  geometry.depth_hr = SceneDepth(width, height);
  geometry.T_world_cam = SE3::Exp((Vector6d() << 0.02, 0.004, -0.01, 0.01, -0.015, 0.004).finished());
  geometry.T_world_neighbour = SE3();
  geometry.stamp = 1.0 / 30.0;
  geometry.neighbour_stamp = 0.0;
  geometry.exposure = 0.8 / 30.0;
  return geometry;
}

double Dot(const cv::Mat& a, const cv::Mat& b) {
  double sum = 0.0;
  const float* pa = a.ptr<float>();
  const float* pb = b.ptr<float>();
  const size_t n = a.total() * a.channels();
  for (size_t i = 0; i < n; ++i) sum += static_cast<double>(pa[i]) * pb[i];
  return sum;
}

cv::Mat RandomImage(cv::Size size, int channels, unsigned seed) {
  cv::Mat image(size, CV_32FC(channels));
  cv::RNG rng(seed);
  rng.fill(image, cv::RNG::UNIFORM, 0.0, 1.0);
  return image;
}

// Psi^T through the transposed copy and by scattering Psi's row runs.
TEST(CaptureOperator, AdjointIdentityOnRandomData) {
  for (int scale : {1, 2, 3}) {
    for (int channels : {1, 3}) {
      for (bool transposed_copy : {true, false}) {
        CaptureOperatorOptions options;
        options.scale = scale;
        options.samples = 17;
        options.transposed_copy = transposed_copy;
        CaptureGeometry geometry = MovingGeometry(48 * scale / scale * 2, 36 * 2);
        if (geometry.camera_hr.width % scale != 0) continue;
        // A neighbour source camera too: the matching-term form of Psi.
        geometry.T_world_source = Translation(-0.03, 0.0, 0.01);
        const CaptureOperator op = BuildCaptureOperator(geometry, options);
        const cv::Mat x = RandomImage(op.hr_size(), channels, 11);
        const cv::Mat y = RandomImage(op.lr_size(), channels, 12);
        cv::Mat psi_x, psi_t_y;
        op.Apply(x, &psi_x);
        op.ApplyAdjoint(y, &psi_t_y);
        const double lhs = Dot(psi_x, y);
        const double rhs = Dot(x, psi_t_y);
        EXPECT_NEAR(lhs, rhs, 1e-5 * std::abs(lhs))
            << "scale " << scale << " channels " << channels << " transposed copy " << transposed_copy;
      }
    }
  }
}

// A rolling shutter gives every LR row its own virtual cameras; the
// transpose stays the exact adjoint, and the rows differ from the global
// shutter's except the first (no delay) away from depth edges.
TEST(CaptureOperator, RollingShutterAdjointIdentityAndFirstRow) {
  CaptureOperatorOptions options;
  options.samples = 17;
  CaptureGeometry geometry = MovingGeometry(96, 72);
  geometry.T_world_source = Translation(-0.03, 0.0, 0.01);
  const CaptureOperator global = BuildCaptureOperator(geometry, options);
  geometry.readout_time = 0.8 * (geometry.stamp - geometry.neighbour_stamp);
  const CaptureOperator rolling = BuildCaptureOperator(geometry, options);
  const cv::Mat x = RandomImage(rolling.hr_size(), 3, 21);
  const cv::Mat y = RandomImage(rolling.lr_size(), 3, 22);
  cv::Mat psi_x, psi_t_y, global_x;
  rolling.Apply(x, &psi_x);
  rolling.ApplyAdjoint(y, &psi_t_y);
  const double lhs = Dot(psi_x, y);
  EXPECT_NEAR(lhs, Dot(x, psi_t_y), 1e-5 * std::abs(lhs));
  global.Apply(x, &global_x);
  const cv::Mat difference = cv::abs(psi_x - global_x);
  // Row 0 reads out with the global shutter's window: the same up to the
  // depth of its virtual cameras (read from the nearest of M reprojections).
  EXPECT_LT(cv::norm(difference.row(0), cv::NORM_L1) / (difference.cols * 3), 0.02);
  const int last = difference.rows - 1;
  EXPECT_GT(cv::norm(difference.row(last), cv::NORM_L1) / (difference.cols * 3), 0.05);
}

TEST(CaptureOperator, ConstantImageStaysConstant) {
  CaptureOperatorOptions options;
  options.samples = 25;
  const CaptureOperator op = BuildCaptureOperator(MovingGeometry(80, 60), options);
  cv::Mat constant(op.hr_size(), CV_32FC3, cv::Scalar(0.25, 0.5, 0.75));
  cv::Mat out;
  op.Apply(constant, &out);
  double max_error = 0.0;
  for (int y = 0; y < out.rows; ++y) {
    for (int x = 0; x < out.cols; ++x) {
      const cv::Vec3f v = out.at<cv::Vec3f>(y, x);
      max_error = std::max({max_error, std::abs(v[0] - 0.25), std::abs(v[1] - 0.5), std::abs(v[2] - 0.75)});
    }
  }
  EXPECT_LT(max_error, 1e-5);
}

TEST(CaptureOperator, ZeroMotionScaleOneIsIdentity) {
  CaptureGeometry geometry = MovingGeometry(40, 30);
  geometry.T_world_neighbour = geometry.T_world_cam;  // no motion
  CaptureOperatorOptions options;
  options.scale = 1;
  options.samples = 10;
  const CaptureOperator op = BuildCaptureOperator(geometry, options);
  const SparseMatrixRM a = op.matrix().ToCsr();
  ASSERT_EQ(a.rows(), 40 * 30);
  ASSERT_EQ(a.cols(), 40 * 30);
  EXPECT_EQ(a.nonZeros(), 40 * 30);
  for (int r = 0; r < a.outerSize(); ++r) {
    for (SparseMatrixRM::InnerIterator it(a, r); it; ++it) {
      EXPECT_EQ(it.col(), r);
      EXPECT_NEAR(it.value(), 1.0f, 1e-6f);
    }
  }
  for (float c : op.coverage()) EXPECT_EQ(c, 1.0f);
}

TEST(CaptureOperator, ZeroMotionIsBoxDownsampling) {
  CaptureGeometry geometry = MovingGeometry(60, 42);
  geometry.T_world_neighbour = geometry.T_world_cam;
  CaptureOperatorOptions options;
  options.scale = 3;
  options.samples = 5;
  const CaptureOperator op = BuildCaptureOperator(geometry, options);
  const cv::Mat image = RandomImage(op.hr_size(), 3, 5);
  cv::Mat ours, reference;
  op.Apply(image, &ours);
  cv::resize(image, reference, op.lr_size(), 0, 0, cv::INTER_AREA);
  EXPECT_LT(cv::norm(ours, reference, cv::NORM_INF), 1e-5);
}

// A fronto-parallel plane and a camera translating along x: every virtual
// camera shifts the image by f b (t - tau) / (dt Z), and bilinear sampling
// reproduces a linear ramp exactly, so the blurred ramp is known in closed
// form. Run both with the previous frame and with the next one as the
// neighbour (backward extrapolation of the first frame).
TEST(CaptureOperator, BlurOfARampMatchesClosedForm) {
  const int width = 120, height = 40, scale = 2, samples = 50;
  const double depth = 2.0, baseline = 0.1, frame_interval = 1.0 / 30.0;
  const double exposure = 0.75 * frame_interval;
  for (bool neighbour_is_next : {false, true}) {
    CaptureGeometry geometry;
    geometry.camera_hr = PinholeCamera(width, height, 300.0, 300.0, 59.5, 19.5);
    geometry.depth_hr = cv::Mat(height, width, CV_32FC1, cv::Scalar(depth));
    geometry.T_world_cam = SE3();
    geometry.stamp = 1.0;
    geometry.exposure = exposure;
    if (neighbour_is_next) {
      geometry.T_world_neighbour = Translation(baseline, 0, 0);
      geometry.neighbour_stamp = 1.0 + frame_interval;
    } else {
      geometry.T_world_neighbour = Translation(-baseline, 0, 0);
      geometry.neighbour_stamp = 1.0 - frame_interval;
    }
    CaptureOperatorOptions options;
    options.scale = scale;
    options.samples = samples;
    const CaptureOperator op = BuildCaptureOperator(geometry, options);
    cv::Mat ramp(height, width, CV_32FC1);
    for (int y = 0; y < height; ++y) {
      for (int x = 0; x < width; ++x) ramp.at<float>(y, x) = 0.01f * x + 0.002f * y + 0.1f;
    }
    cv::Mat blurred;
    op.Apply(ramp, &blurred);
    // Mean shift (HR px) of the virtual cameras at the slice midpoints: half
    // the blur, f b/Z * e/dt / 2 (the paper's m/M would give (M-1)/(2M)).
    const double mean_shift = 300.0 * baseline / depth * exposure / frame_interval / 2.0;
    const double max_shift = 300.0 * baseline / depth * exposure / frame_interval;
    ASSERT_GT(max_shift, 8.0);  // a severe blur, as in the paper
    int checked = 0;
    for (int y = 0; y < blurred.rows; ++y) {
      for (int x = 0; x < blurred.cols; ++x) {
        if (op.coverage()[y * blurred.cols + x] < 1.0f) continue;
        const double hr_x = scale * x + (scale - 1) / 2.0 - mean_shift;
        const double hr_y = scale * y + (scale - 1) / 2.0;
        EXPECT_NEAR(blurred.at<float>(y, x), 0.01 * hr_x + 0.002 * hr_y + 0.1, 2e-5);
        ++checked;
      }
    }
    // Pixels within the blur length of the left border miss samples.
    EXPECT_GT(checked, blurred.total() * 3 / 4);
    EXPECT_LT(checked, static_cast<int>(blurred.total()));
  }
}

TEST(CaptureOperator, RejectsInconsistentInput) {
  CaptureGeometry geometry = MovingGeometry(40, 30);
  CaptureOperatorOptions options;
  options.scale = 4;  // 30 is not divisible by 4
  EXPECT_THROW(BuildCaptureOperator(geometry, options), InputError);
  options.scale = 2;
  geometry.exposure = 0.0;
  EXPECT_THROW(BuildCaptureOperator(geometry, options), InputError);
  geometry = MovingGeometry(40, 30);
  geometry.neighbour_stamp = geometry.stamp;
  EXPECT_THROW(BuildCaptureOperator(geometry, options), InputError);
  geometry = MovingGeometry(40, 30);
  geometry.depth_hr = cv::Mat(10, 10, CV_32FC1, cv::Scalar(1.0f));
  EXPECT_THROW(BuildCaptureOperator(geometry, options), InputError);
  options.samples = 0;
  ExpectInputError([&] { options.Check(); }, "capture operator: samples (M) must be in [1, 10000], got 0");
  options = CaptureOperatorOptions();
  options.num_threads = -2;
  ExpectInputError([&] { options.Check(); }, "capture operator: num_threads must be >= 0, got -2");
  const CaptureOperator op = BuildCaptureOperator(MovingGeometry(40, 30), CaptureOperatorOptions());
  cv::Mat wrong(7, 7, CV_32FC1, cv::Scalar(0)), out;
  EXPECT_THROW(op.Apply(wrong, &out), InputError);
}

// An 80 x 60 camera seeing a square at 1 m in front of a plane at 4 m.
struct SquareBeforePlane {
  PinholeCamera camera{80, 60, 100.0, 100.0, 39.5, 29.5};
  cv::Rect square{30, 20, 20, 20};
  cv::Mat depth;
  SquareBeforePlane() : depth(60, 80, CV_32FC1, cv::Scalar(4.0f)) { depth(square).setTo(1.0f); }
};

// A near square in front of a far plane; the second camera moves sideways,
// so part of the plane next to the square is hidden behind it from s.
TEST(Visibility, OccludedBackgroundIsNotVisible) {
  const SquareBeforePlane scene;
  const PinholeCamera& camera = scene.camera;
  const cv::Mat& depth = scene.depth;
  const cv::Rect& square = scene.square;
  // Camera s is 0.1 m to the right: near points shift left by f b/Z = 10 px,
  // far ones by 2.5 px, so the plane just left of the square is covered.
  const SE3 T_s_t = Translation(-0.1, 0.0, 0.0);
  const cv::Mat visible = ComputeVisibility(camera, depth, T_s_t, VisibilityOptions());
  // The whole square is visible (nearest), minus nothing.
  EXPECT_EQ(cv::countNonZero(visible(square)), square.area());
  // Background pixels from 3 to 7 px left of the square land on the square's
  // image in s: hidden.
  for (int y = 22; y < 38; ++y) {
    for (int x = 23; x <= 27; ++x) EXPECT_EQ(visible.at<uchar>(y, x), 0) << x << "," << y;
  }
  // Far from the square the plane is visible; near the left border it leaves the image.
  EXPECT_EQ(visible.at<uchar>(10, 70), 255);
  EXPECT_EQ(visible.at<uchar>(10, 0), 0);
  const cv::Mat visible_lr = DownscaleMaskAll(visible, 2);
  EXPECT_EQ(visible_lr.at<uchar>(15, 12), 0);
  EXPECT_EQ(visible_lr.at<uchar>(5, 35), 255);
}

// A near square (1 m) in front of a far plane (4 m); camera s is 0.3 m
// closer, so the square's image grows by 1 / 0.7 = 1.43 and the forward splat
// of D_t leaves empty cells inside it: background pixels of t whose rays land
// in those holes pass D_t's own occlusion test although s sees the square
// there. With s's depth map (VisibilityOptions::source_depth_margin) every
// one of them is left out, and nothing that s sees is.
TEST(Visibility, SourceDepthFindsOccludedPixelsThatTheSplatMisses) {
  const SquareBeforePlane scene;
  const PinholeCamera& camera = scene.camera;
  const cv::Mat& depth_t = scene.depth;
  const cv::Rect& square = scene.square;
  const int width = camera.width, height = camera.height;
  const SE3 T_s_t = Translation(0.0, 0.0, -0.3);
  // D_s: the square's continuous extent [29.5, 49.5] x [19.5, 39.5] of t at
  // 0.7 m, seen from s; the plane at 3.7 m.
  const auto to_s = [](double t_coordinate, double centre) { return centre + (t_coordinate - centre) / 0.7; };
  const cv::Rect2d square_s(cv::Point2d(to_s(29.5, 39.5), to_s(19.5, 29.5)),
                            cv::Point2d(to_s(49.5, 39.5), to_s(39.5, 29.5)));
  cv::Mat depth_s(height, width, CV_32FC1, cv::Scalar(3.7f));
  for (int v = 0; v < height; ++v) {
    for (int u = 0; u < width; ++u) {
      if (square_s.contains(cv::Point2d(u, v))) depth_s.at<float>(v, u) = 0.7f;
    }
  }
  VisibilityOptions options;
  const cv::Mat own = ComputeVisibility(camera, depth_t, T_s_t, options, &depth_s);  // margin 0: ignored
  options.source_depth_margin = 0.02;
  const cv::Mat both = ComputeVisibility(camera, depth_t, T_s_t, options, &depth_s);
  EXPECT_EQ(cv::countNonZero(own != ComputeVisibility(camera, depth_t, T_s_t, VisibilityOptions())), 0);
  // Background pixels whose rays land at least one pixel inside the square's
  // image in s are occluded there.
  int occluded = 0, kept_by_own = 0, kept_by_both = 0;
  const cv::Rect2d inner(square_s.x + 1.0, square_s.y + 1.0, square_s.width - 2.0, square_s.height - 2.0);
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      if (square.contains(cv::Point(x, y))) continue;
      const cv::Point2d landing(39.5 + (x - 39.5) * 4.0 / 3.7, 29.5 + (y - 29.5) * 4.0 / 3.7);
      if (!inner.contains(landing)) continue;
      ++occluded;
      kept_by_own += own.at<uchar>(y, x) != 0;
      kept_by_both += both.at<uchar>(y, x) != 0;
    }
  }
  ASSERT_GT(occluded, 50);
  EXPECT_GT(kept_by_own, occluded / 10) << occluded;  // the splat's holes
  EXPECT_EQ(kept_by_both, 0);
  // What s sees is still visible: the whole square, and the plane away from it.
  EXPECT_EQ(cv::countNonZero(both(square)), square.area());
  EXPECT_EQ(cv::countNonZero(both(cv::Rect(0, 0, width, 8))), cv::countNonZero(own(cv::Rect(0, 0, width, 8))));
  EXPECT_GT(cv::countNonZero(both(cv::Rect(0, 0, width, 8))), 0);
  // A source depth of the wrong size is an input error.
  const cv::Mat small(10, 10, CV_32FC1, cv::Scalar(1.0f));
  EXPECT_THROW(ComputeVisibility(camera, depth_t, T_s_t, options, &small), InputError);
}

TEST(EdgeWeight, FlatIsOneAndEdgesAreSmall) {
  cv::Mat image(20, 20, CV_32FC1, cv::Scalar(0.3f));
  image.colRange(10, 20).setTo(0.9f);
  const cv::Mat g = EdgeWeight(image, EdgeWeightOptions());
  EXPECT_FLOAT_EQ(g.at<float>(5, 3), 1.0f);
  EXPECT_LT(g.at<float>(5, 9), 0.05f);
  EdgeWeightOptions bad;
  bad.sigma = 0.0;
  ExpectInputError([&] { EdgeWeight(image, bad); }, "edge weight: sigma must be > 0, got 0");
  bad = EdgeWeightOptions();
  bad.exponent = -1.0;
  ExpectInputError([&] { bad.Check(); }, "edge weight: exponent must be > 0, got -1");
  VisibilityOptions visibility;
  visibility.depth_tolerance = 1.0;
  ExpectInputError([&] { visibility.Check(); }, "visibility: depth_tolerance must be in [0, 1), got 1");
  visibility.depth_tolerance = -0.5;
  ExpectInputError([&] { visibility.Check(); }, "visibility: depth_tolerance must be in [0, 1), got -0.5");
  visibility = VisibilityOptions();
  visibility.source_depth_margin = -0.1;
  ExpectInputError([&] { visibility.Check(); }, "visibility: source_depth_margin must be in [0, 1), got -0.1");
}

// Two consecutive frames of a constant-velocity path parallel to a
// fronto-parallel plane blur every point alike: their blur difference is 0,
// with a global and with a rolling shutter. Halving the second frame's
// exposure halves its blur vectors, and the difference is then half of the
// blur length f b / d; a second frame that sees none of the first's points
// gives NaN (no evidence either way).
TEST(BlurDifference, ZeroOnAConstantVelocityPathAndTheChangeOfBlurOtherwise) {
  CaptureGeometry a = MovingGeometry(96, 72);
  a.depth_hr.setTo(2.0f);
  a.T_world_neighbour = SE3();
  a.T_world_cam = Translation(0.09, 0.0, 0.0);
  CaptureGeometry b = a;
  b.T_world_neighbour = a.T_world_cam;
  b.neighbour_stamp = a.stamp;
  b.T_world_cam = Translation(0.18, 0.0, 0.0);
  b.stamp = 2.0 * a.stamp;
  const double blur_length = BlurLengthHr(a, 2);
  ASSERT_GT(blur_length, 2.0);
  EXPECT_NEAR(BlurDifferenceHr(a, b, 2), 0.0, 1e-9);
  EXPECT_NEAR(BlurDifferenceHr(b, a, 2), 0.0, 1e-9);
  {
    CaptureGeometry rolling_a = a, rolling_b = b;
    rolling_a.readout_time = rolling_b.readout_time = 0.8 * a.stamp;
    EXPECT_NEAR(BlurDifferenceHr(rolling_a, rolling_b, 2), 0.0, 1e-9);
  }
  CaptureGeometry shorter = b;
  shorter.exposure = 0.5 * a.exposure;
  EXPECT_NEAR(BlurDifferenceHr(a, shorter, 2), 0.5 * blur_length, 1e-6 * blur_length);
  CaptureGeometry away = b;
  away.T_world_cam = SE3(Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitY()).toRotationMatrix(),
                         Eigen::Vector3d(0.18, 0.0, 0.0));
  away.T_world_neighbour = away.T_world_cam;
  EXPECT_TRUE(std::isnan(BlurDifferenceHr(a, away, 2)));
}

}  // namespace
}  // namespace deblur_sr_mvs

namespace deblur_sr_mvs {
namespace {

// Without the transposed copy Psi^T scatters through Psi: same result.
TEST(CaptureOperator, AdjointWithoutTransposedCopyIsTheSame) {
  CaptureOperatorOptions options;
  options.samples = 13;
  const CaptureOperator with_copy = BuildCaptureOperator(MovingGeometry(60, 40), options);
  options.transposed_copy = false;
  const CaptureOperator without_copy = BuildCaptureOperator(MovingGeometry(60, 40), options);
  const cv::Mat y = RandomImage(with_copy.lr_size(), 3, 21);
  cv::Mat a, b;
  with_copy.ApplyAdjoint(y, &a);
  without_copy.ApplyAdjoint(y, &b);
  EXPECT_LT(cv::norm(a, b, cv::NORM_INF), 1e-5);
}

}  // namespace
}  // namespace deblur_sr_mvs

namespace deblur_sr_mvs {
namespace {

// The same matrix (structure and bits) and the same coverage.
void ExpectSameOperator(const CaptureOperator& a, const CaptureOperator& b, const std::string& what) {
  const SparseMatrixRM ma = a.matrix().ToCsr();
  const SparseMatrixRM mb = b.matrix().ToCsr();
  ASSERT_EQ(ma.rows(), mb.rows()) << what;
  ASSERT_EQ(ma.cols(), mb.cols()) << what;
  ASSERT_EQ(ma.nonZeros(), mb.nonZeros()) << what;
  EXPECT_TRUE(std::equal(ma.outerIndexPtr(), ma.outerIndexPtr() + ma.rows() + 1, mb.outerIndexPtr())) << what;
  EXPECT_TRUE(std::equal(ma.innerIndexPtr(), ma.innerIndexPtr() + ma.nonZeros(), mb.innerIndexPtr())) << what;
  // Bitwise: memcmp, not ==, so that -0 and 0 would differ.
  EXPECT_EQ(std::memcmp(ma.valuePtr(), mb.valuePtr(), sizeof(float) * ma.nonZeros()), 0) << what;
  EXPECT_EQ(a.coverage(), b.coverage()) << what;
}

// The virtual depths of a frame, computed once, give the operators of every
// source exactly what each build alone gives (global and rolling shutter,
// fixed and adaptive M).
TEST(CaptureOperator, SharedVirtualDepthsGiveTheSameOperator) {
  for (const double readout_ratio : {0.0, 0.8}) {
    for (const bool adaptive : {false, true}) {
      CaptureOperatorOptions options;
      options.samples = 17;
      options.adaptive_samples = adaptive;
      CaptureGeometry geometry = MovingGeometry(96, 72);
      geometry.readout_time = readout_ratio * (geometry.stamp - geometry.neighbour_stamp);
      VirtualDepths shared;
      shared.Compute(geometry, options);
      CaptureOperatorBuilder builder(options);
      for (const std::optional<SE3>& source :
           {std::optional<SE3>(), std::optional<SE3>(Translation(-0.03, 0.0, 0.01)),
            std::optional<SE3>(SE3::Exp((Vector6d() << 0.05, -0.01, 0.02, 0.0, 0.02, -0.01).finished()))}) {
        geometry.T_world_source = source;
        const CaptureOperator alone = BuildCaptureOperator(geometry, options);
        CaptureOperator with_shared;
        builder.Build(geometry, shared, &with_shared);
        ExpectSameOperator(alone, with_shared,
                           "readout " + std::to_string(readout_ratio) + (adaptive ? " adaptive" : " fixed") +
                               (source ? " neighbour source" : " own source"));
      }
    }
  }
}

TEST(CaptureOperator, SharedVirtualDepthsOfAnotherStructureAreRejected) {
  CaptureOperatorOptions options;
  options.samples = 9;
  const CaptureGeometry geometry = MovingGeometry(48, 36);
  VirtualDepths shared;
  shared.Compute(geometry, options);
  CaptureOperatorBuilder builder(options);
  CaptureOperator op;
  const std::string message =
      "capture operator: the shared virtual depths were computed for another frame structure";
  CaptureGeometry moved = geometry;
  moved.T_world_neighbour = Translation(0.001, 0.0, 0.0);
  ExpectInputError([&] { builder.Build(moved, shared, &op); }, message);
  CaptureGeometry other_depth = geometry;
  other_depth.depth_hr = geometry.depth_hr.clone();  // same values, another buffer
  ExpectInputError([&] { builder.Build(other_depth, shared, &op); }, message);
  options.samples = 10;
  CaptureOperatorBuilder other_samples(options);
  ExpectInputError([&] { other_samples.Build(geometry, shared, &op); }, message);
}

// Which frames fix a frame's blur path, and SetBlurPath's choice of them.
TEST(BlurPath, FramesOfTheFirstInteriorAndLastFrame) {
  EXPECT_EQ(BlurPathFrames(0, 2), (std::vector<int>{1}));
  EXPECT_EQ(BlurPathFrames(1, 2), (std::vector<int>{0}));
  EXPECT_EQ(BlurPathFrames(0, 3), (std::vector<int>{1, 2}));
  EXPECT_EQ(BlurPathFrames(1, 3), (std::vector<int>{0, 2}));
  EXPECT_EQ(BlurPathFrames(2, 3), (std::vector<int>{1, 0}));
  EXPECT_EQ(BlurPathFrames(0, 5), (std::vector<int>{1, 2}));
  EXPECT_EQ(BlurPathFrames(1, 5), (std::vector<int>{0, 2, 3}));
  EXPECT_EQ(BlurPathFrames(2, 5), (std::vector<int>{1, 3, 0}));
  EXPECT_EQ(BlurPathFrames(4, 5), (std::vector<int>{3, 2}));
  EXPECT_THROW(BlurPathFrames(0, 1), InputError);
  EXPECT_THROW(BlurPathFrames(5, 5), InputError);
  std::vector<SE3> poses;
  std::vector<double> stamps;
  for (int t = 0; t < 5; ++t) {
    poses.push_back(Translation(0.01 * t * t, 0.0, 0.0));
    stamps.push_back(0.1 * t);
  }
  for (int t = 0; t < 5; ++t) {
    CaptureGeometry geometry;
    SetBlurPath(poses, stamps, t, &geometry);
    const std::vector<int> path = BlurPathFrames(t, 5);
    EXPECT_EQ(geometry.stamp, stamps[t]);
    EXPECT_EQ(geometry.neighbour_stamp, stamps[path[0]]);
    EXPECT_EQ(geometry.T_world_second_neighbour.has_value(), path.size() >= 2);
    EXPECT_EQ(geometry.T_world_third_neighbour.has_value(), path.size() == 3);
    // Through every pose that fixes it, at its stamp.
    EXPECT_LT((PoseAtTime(geometry, stamps[t]).translation() - poses[t].translation()).norm(), 1e-12);
    for (int frame : path) {
      EXPECT_LT((PoseAtTime(geometry, stamps[frame]).translation() - poses[frame].translation()).norm(), 1e-12)
          << t << " " << frame;
    }
    // The poses lie on one constant acceleration (x = 0.01 (tau / 0.1)^2):
    // every frame's path is that parabola over its exposure (0.8 of the
    // interval), the first frame's extrapolated backwards and the last's
    // interpolated. The geodesics through two frames missed the first
    // frame's opening by 0.0144 and the last's by 0.0016 here.
    for (double fraction : {0.0, 0.4, 0.8}) {
      const double tau = stamps[t] - fraction * 0.1;
      EXPECT_LT(std::abs(PoseAtTime(geometry, tau).translation().x() - tau * tau), 1e-12)
          << t << " " << fraction;
    }
  }
  // On a changing acceleration (x = (tau / 0.1)^3 / 100) the cubic paths of
  // the interior frames follow it over their exposures; the quadratics of
  // the first and last frames do not.
  for (int t = 0; t < 5; ++t) poses[t] = Translation(0.01 * t * t * t, 0.0, 0.0);
  for (int t = 0; t < 5; ++t) {
    CaptureGeometry geometry;
    SetBlurPath(poses, stamps, t, &geometry);
    const double tau = stamps[t] - 0.8 * 0.1;
    const double error = std::abs(PoseAtTime(geometry, tau).translation().x() - 10.0 * tau * tau * tau);
    if (t == 0 || t == 4) {
      EXPECT_GT(error, 1e-4) << t;
    } else {
      EXPECT_LT(error, 1e-12) << t;
    }
  }
}

// The virtual cameras of a curved path are its poses at the sample times, and
// a constant-velocity curve gives the operator of the geodesic (to rounding).
TEST(BlurPath, VirtualCamerasFollowTheCurve) {
  CaptureGeometry geometry = MovingGeometry(48, 36);
  const SE3 T_world_next = SE3::Exp((Vector6d() << 0.05, -0.01, 0.0, 0.0, 0.02, -0.01).finished());
  geometry.T_world_second_neighbour = T_world_next;
  geometry.second_neighbour_stamp = 2.0 / 30.0;
  const int samples = 7;
  const std::vector<SE3> poses = VirtualCameraPoses(geometry, samples);
  for (int m = 0; m < samples; ++m) {
    const double tau = geometry.stamp - geometry.exposure + (m + 0.5) / samples * geometry.exposure;
    const SE3 expected = PoseOnQuadraticPath(geometry.T_world_neighbour, geometry.neighbour_stamp, T_world_next,
                                             geometry.second_neighbour_stamp, geometry.T_world_cam,
                                             geometry.stamp, tau);
    EXPECT_LT((poses[m].Matrix() - expected.Matrix()).cwiseAbs().maxCoeff(), 1e-15) << m;
  }
  // The same three poses on one constant-velocity path: the geodesic's operator.
  CaptureGeometry straight = geometry;
  straight.T_world_second_neighbour.reset();
  CaptureGeometry constant = straight;
  constant.T_world_second_neighbour =
      PoseAtTime(straight.T_world_neighbour, straight.neighbour_stamp, straight.T_world_cam, straight.stamp,
                 2.0 / 30.0);
  CaptureOperatorOptions options;
  options.samples = 9;
  const CaptureOperator a = BuildCaptureOperator(straight, options);
  const CaptureOperator b = BuildCaptureOperator(constant, options);
  cv::Mat hr(36, 48, CV_32FC1), lr_a, lr_b;
  cv::randu(hr, 0.0, 1.0);
  a.Apply(hr, &lr_a);
  b.Apply(hr, &lr_b);
  EXPECT_LT(cv::norm(lr_a, lr_b, cv::NORM_INF), 1e-5);
  EXPECT_FALSE(SameCaptureGeometry(straight, constant));  // the cache still tells them apart
  CaptureGeometry moved = constant;
  moved.T_world_second_neighbour = Translation(0.0, 0.001, 0.0) * *constant.T_world_second_neighbour;
  EXPECT_FALSE(SameCaptureGeometry(constant, moved));
  moved = constant;
  moved.second_neighbour_stamp += 1e-6;
  EXPECT_FALSE(SameCaptureGeometry(constant, moved));
  CaptureGeometry cubic = constant;
  cubic.T_world_third_neighbour = SE3::Exp((Vector6d() << -0.02, 0.0, 0.01, 0.0, 0.01, 0.0).finished());
  cubic.third_neighbour_stamp = -1.0 / 30.0;
  EXPECT_FALSE(SameCaptureGeometry(constant, cubic));
  moved = cubic;
  moved.T_world_third_neighbour = Translation(0.0, 0.001, 0.0) * *cubic.T_world_third_neighbour;
  EXPECT_FALSE(SameCaptureGeometry(cubic, moved));
  moved = cubic;
  moved.third_neighbour_stamp += 1e-6;
  EXPECT_FALSE(SameCaptureGeometry(cubic, moved));
  EXPECT_TRUE(SameCaptureGeometry(constant, CaptureGeometry(constant)));
  EXPECT_TRUE(SameCaptureGeometry(cubic, CaptureGeometry(cubic)));
}

// MoveBlurPath keeps the motion in the camera frame: P_t^-1 P(tau) is the
// same along the moved path at the shifted times.
TEST(BlurPath, MovedPathKeepsTheRelativeMotion) {
  CaptureGeometry geometry = MovingGeometry(48, 36);
  geometry.T_world_second_neighbour = SE3::Exp((Vector6d() << 0.05, -0.01, 0.0, 0.0, 0.02, -0.01).finished());
  geometry.second_neighbour_stamp = 2.0 / 30.0;
  geometry.T_world_third_neighbour = SE3::Exp((Vector6d() << -0.02, 0.0, 0.01, 0.0, 0.01, 0.0).finished());
  geometry.third_neighbour_stamp = -1.0 / 30.0;
  CaptureGeometry moved = geometry;
  const SE3 T_world_target = SE3::Exp((Vector6d() << -0.3, 0.1, 0.2, 0.1, -0.2, 0.05).finished());
  MoveBlurPath(T_world_target, 5.0, &moved);
  EXPECT_EQ(moved.stamp, 5.0);
  for (double offset : {-0.05, -0.02, 0.0, 0.01}) {
    const SE3 original = geometry.T_world_cam.Inverse() * PoseAtTime(geometry, geometry.stamp + offset);
    const SE3 shifted = T_world_target.Inverse() * PoseAtTime(moved, 5.0 + offset);
    EXPECT_LT((original.Matrix() - shifted.Matrix()).cwiseAbs().maxCoeff(), 1e-9) << offset;
  }
}

// A camera translating parallel to a fronto-parallel plane at depth d moves
// every image point by f b / d over the exposure (b: the baseline covered
// while the shutter is open); adaptive M is that length, clamped.
TEST(CaptureOperator, AdaptiveSamplesFollowTheBlurLength) {
  CaptureGeometry geometry = MovingGeometry(96, 72);
  geometry.depth_hr.setTo(2.0f);
  geometry.T_world_neighbour = SE3();
  geometry.T_world_cam = Translation(0.09, 0.0, 0.0);
  const double baseline = 0.09 * geometry.exposure / (geometry.stamp - geometry.neighbour_stamp);
  const double expected = geometry.camera_hr.fx * baseline / 2.0;  // ~3.1 px
  EXPECT_NEAR(BlurLengthHr(geometry, 2), expected, 1e-6 * expected);
  {
    // A rolling shutter: every row's window is as long, at the same speed.
    CaptureGeometry rolling = geometry;
    rolling.readout_time = 0.8 * (geometry.stamp - geometry.neighbour_stamp);
    EXPECT_NEAR(BlurLengthHr(rolling, 2), expected, 1e-6 * expected);
  }
  CaptureOperatorOptions options;
  options.samples = 50;
  EXPECT_EQ(CaptureSamples(geometry, options), 50);  // adaptive off: M itself
  options.adaptive_samples = true;
  EXPECT_EQ(CaptureSamples(geometry, options), static_cast<int>(std::ceil(expected)));
  options.samples_per_pixel = 2.0;
  EXPECT_EQ(CaptureSamples(geometry, options), static_cast<int>(std::ceil(2.0 * expected)));
  {
    // A rolling shutter: each row's M samples span its own exposure, so M
    // is the global shutter's; its reprojected depths span the exposure plus
    // the readout of all but the last LR row, and their number K follows the
    // motion over that span, at twice the samples' density.
    CaptureGeometry rolling = geometry;
    rolling.readout_time = 0.8 * (geometry.stamp - geometry.neighbour_stamp);
    const int lr_rows = geometry.camera_hr.height / 2;
    const double span = geometry.exposure + rolling.readout_time * (lr_rows - 1) / lr_rows;
    EXPECT_EQ(CaptureSamples(rolling, options), static_cast<int>(std::ceil(2.0 * expected)));
    EXPECT_EQ(DepthCameraCount(rolling, options),
              static_cast<int>(std::ceil(2.0 * 2.0 * expected * span / geometry.exposure)));
    EXPECT_EQ(DepthCameraCount(geometry, options), CaptureSamples(geometry, options));  // global: K = M
    options.adaptive_samples = false;
    EXPECT_EQ(DepthCameraCount(rolling, options), options.samples);
    options.adaptive_samples = true;
  }
  options.samples = 5;  // the cap
  EXPECT_EQ(CaptureSamples(geometry, options), 5);
  // No motion: the floor; unknown depth does not move either.
  options.samples = 50;
  geometry.T_world_cam = SE3();
  EXPECT_EQ(BlurLengthHr(geometry, 2), 0.0);
  EXPECT_EQ(CaptureSamples(geometry, options), options.min_samples);
  geometry.T_world_cam = Translation(0.09, 0.0, 0.0);
  geometry.depth_hr.setTo(std::numeric_limits<float>::quiet_NaN());
  EXPECT_EQ(CaptureSamples(geometry, options), options.min_samples);
}

// A blurred frame re-centred on the shutter close shows the close camera's
// content: the operator's blur of a ramp (which a symmetric blur leaves a
// ramp, moved by half the blur) comes back to the ramp itself, on a global
// and a rolling shutter (each row at its own mid-exposure), the previous or
// the next frame as the path's neighbour; pixels whose mid-exposure point
// leaves the image are not valid.
TEST(RecentreOnShutterClose, BlurredRampComesBackOnTheCloseCamera) {
  const int width = 120, height = 40;
  const double depth = 2.0, baseline = 0.1, frame_interval = 1.0 / 30.0;
  const double exposure = 0.75 * frame_interval;
  cv::Mat ramp(height, width, CV_32FC1);
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) ramp.at<float>(y, x) = 0.01f * x + 0.002f * y + 0.1f;
  }
  const cv::Mat inverse_depth(height, width, CV_32FC1, cv::Scalar(1.0 / depth));
  for (bool neighbour_is_next : {false, true}) {
    for (double readout : {0.0, 0.6 * frame_interval}) {
      CaptureGeometry geometry;
      geometry.camera_hr = PinholeCamera(width, height, 300.0, 300.0, 59.5, 19.5);
      geometry.depth_hr = cv::Mat(height, width, CV_32FC1, cv::Scalar(depth));
      geometry.stamp = 1.0;
      geometry.exposure = exposure;
      geometry.readout_time = readout;
      geometry.T_world_neighbour = Translation(neighbour_is_next ? baseline : -baseline, 0, 0);
      geometry.neighbour_stamp = neighbour_is_next ? 1.0 + frame_interval : 1.0 - frame_interval;
      CaptureOperatorOptions options;
      options.scale = 1;  // blurred at HR, as the up-sampled inputs
      options.samples = 50;
      cv::Mat blurred, recentred, valid;
      BuildCaptureOperator(geometry, options).Apply(ramp, &blurred);
      RecentreOnShutterClose(geometry, 1, inverse_depth, blurred, &recentred, &valid);
      ASSERT_EQ(recentred.size(), ramp.size());
      // The blur is f b / Z e / dt = 11.25 px (the last row's centre moves
      // by up to 0.6 / 0.75 of it more with the readout); away from the
      // borders (one pixel at the top and the bottom) every pixel is covered
      // and valid.
      int checked = 0;
      for (int y = 1; y < height - 1; ++y) {
        for (int x = 25; x < width - 25; ++x) {
          ASSERT_EQ(valid.at<uint8_t>(y, x), 255) << x << " " << y;
          EXPECT_NEAR(recentred.at<float>(y, x), ramp.at<float>(y, x), 2e-4) << x << " " << y;
          ++checked;
        }
      }
      EXPECT_GT(checked, 2000);
      // The camera moves towards +x in both cases (the previous frame at -b,
      // or the next at +b): in the middle row the mid-exposure camera lies
      // behind, points appear further right, and the rightmost column's
      // leave the image.
      EXPECT_EQ(valid.at<uint8_t>(height / 2, width - 1), 0);
      EXPECT_EQ(valid.at<uint8_t>(height / 2, 1), 255);
    }
  }
}

}  // namespace
}  // namespace deblur_sr_mvs
