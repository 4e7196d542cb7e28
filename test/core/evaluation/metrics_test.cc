#include "deblur_sr_mvs/core/evaluation/metrics.h"

#include <cmath>
#include <limits>
#include <random>

#include <gtest/gtest.h>
#include <Eigen/Geometry>
#include <Eigen/LU>

#include "deblur_sr_mvs/core/common/errors.h"

namespace deblur_sr_mvs {
namespace {

constexpr double kNan = std::numeric_limits<double>::quiet_NaN();
constexpr double kInf = std::numeric_limits<double>::infinity();

// ------------------------------------------------------------------ PSNR

TEST(PsnrTest, GrayMatchesHandComputedValue) {
  const cv::Mat reference = (cv::Mat_<uint8_t>(2, 2) << 10, 20, 30, 40);
  const cv::Mat estimate = (cv::Mat_<uint8_t>(2, 2) << 12, 20, 30, 36);
  // Squared errors 4, 0, 0, 16: MSE = 5.
  EXPECT_NEAR(Psnr(estimate, reference, 255.0), 10.0 * std::log10(255.0 * 255.0 / 5.0), 1e-12);
  // Masking out the last pixel leaves 4, 0, 0: MSE = 4/3.
  const cv::Mat mask = (cv::Mat_<uint8_t>(2, 2) << 1, 255, 7, 0);
  EXPECT_NEAR(Psnr(estimate, reference, 255.0, mask), 10.0 * std::log10(255.0 * 255.0 * 3.0 / 4.0), 1e-12);
  // Masking out the only differing pixels gives a perfect match.
  const cv::Mat exact_mask = (cv::Mat_<uint8_t>(2, 2) << 0, 1, 1, 0);
  EXPECT_EQ(Psnr(estimate, reference, 255.0, exact_mask), kInf);
  EXPECT_EQ(Psnr(reference, reference, 255.0), kInf);
}

TEST(PsnrTest, ColourAveragesOverChannels) {
  cv::Mat reference(1, 2, CV_8UC3, cv::Scalar(0, 0, 0));
  reference.at<cv::Vec3b>(0, 1) = cv::Vec3b(10, 10, 10);
  cv::Mat estimate = reference.clone();
  estimate.at<cv::Vec3b>(0, 0) = cv::Vec3b(3, 0, 0);
  estimate.at<cv::Vec3b>(0, 1) = cv::Vec3b(10, 10, 14);
  // Squared errors 9, 0, 0 | 0, 0, 16 over 6 values.
  EXPECT_NEAR(Psnr(estimate, reference, 255.0), 10.0 * std::log10(255.0 * 255.0 * 6.0 / 25.0), 1e-12);
  const cv::Mat mask = (cv::Mat_<uint8_t>(1, 2) << 0, 1);
  EXPECT_NEAR(Psnr(estimate, reference, 255.0, mask), 10.0 * std::log10(255.0 * 255.0 * 3.0 / 16.0), 1e-12);
}

TEST(PsnrTest, FloatImagesAndErrors) {
  const cv::Mat reference = (cv::Mat_<float>(1, 2) << 0.5f, 0.25f);
  const cv::Mat estimate = (cv::Mat_<float>(1, 2) << 0.75f, 0.25f);
  // MSE = 0.0625 / 2.
  EXPECT_NEAR(Psnr(estimate, reference, 1.0), 10.0 * std::log10(2.0 / 0.0625), 1e-12);
  EXPECT_THROW(Psnr(estimate, cv::Mat(1, 3, CV_32FC1), 1.0), InputError);
  EXPECT_THROW(Psnr(estimate, cv::Mat(1, 2, CV_64FC1), 1.0), InputError);
  EXPECT_THROW(Psnr(estimate, reference, 0.0), InputError);
  EXPECT_THROW(Psnr(estimate, reference, 1.0, cv::Mat::zeros(1, 2, CV_8UC1)), InputError);
  EXPECT_THROW(Psnr(estimate, reference, 1.0, cv::Mat::ones(2, 1, CV_8UC1)), InputError);
}

// ------------------------------------------------------------- centre crop

TEST(CentreCropTest, CentredRoundedRectangle) {
  EXPECT_EQ(CentreCrop(cv::Size(10, 20), 0.7), cv::Rect(1, 3, 7, 14));
  EXPECT_EQ(CentreCrop(cv::Size(10, 20), 1.0), cv::Rect(0, 0, 10, 20));
  EXPECT_EQ(CentreCrop(cv::Size(4, 4), 0.5), cv::Rect(1, 1, 2, 2));
  EXPECT_EQ(CentreCrop(cv::Size(640, 480), 0.7), cv::Rect(96, 72, 448, 336));
  EXPECT_THROW(CentreCrop(cv::Size(10, 10), 0.0), InputError);
  EXPECT_THROW(CentreCrop(cv::Size(10, 10), 1.5), InputError);
}

// ------------------------------------------------------------ depth metrics

// 4x4 maps; the centre 2x2 (crop 0.5) holds gt 2, 4, 6, 8 and est 1, 2, 4, NaN.
// Outside: invalid pixels (gt 0, est -1, est inf) and nine with gt 100, est 1.
void MakeDepthPair(cv::Mat* estimate, cv::Mat* ground_truth) {
  *estimate = cv::Mat(4, 4, CV_32FC1, cv::Scalar(1.0f));
  *ground_truth = cv::Mat(4, 4, CV_32FC1, cv::Scalar(100.0f));
  ground_truth->at<float>(1, 1) = 2.0f;
  ground_truth->at<float>(1, 2) = 4.0f;
  ground_truth->at<float>(2, 1) = 6.0f;
  ground_truth->at<float>(2, 2) = 8.0f;
  estimate->at<float>(1, 1) = 1.0f;
  estimate->at<float>(1, 2) = 2.0f;
  estimate->at<float>(2, 1) = 4.0f;
  estimate->at<float>(2, 2) = std::numeric_limits<float>::quiet_NaN();
  ground_truth->at<float>(0, 0) = 0.0f;
  estimate->at<float>(0, 3) = -1.0f;
  estimate->at<float>(3, 0) = std::numeric_limits<float>::infinity();
}

TEST(EvaluateDepthTest, CropAndScaleAlignmentMatchHandComputedValues) {
  cv::Mat estimate;
  cv::Mat ground_truth;
  MakeDepthPair(&estimate, &ground_truth);
  DepthMetricOptions options;
  options.crop_fraction = 0.5;

  // Ratios 2, 2, 1.5: s = 2; s*est = 2, 4, 8 vs gt 2, 4, 6.
  DepthErrors errors = EvaluateDepth(estimate, ground_truth, options);
  EXPECT_EQ(errors.num_pixels, 3);
  EXPECT_DOUBLE_EQ(errors.scale, 2.0);
  EXPECT_NEAR(errors.relative_error, (2.0 / 6.0) / 3.0, 1e-12);
  // MSE = 4/3, peak = 6 (the 8 has no valid estimate).
  EXPECT_NEAR(errors.psnr_db, 10.0 * std::log10(36.0 / (4.0 / 3.0)), 1e-12);

  // Without alignment: est 1, 2, 4 vs gt 2, 4, 6.
  options.align_scale = false;
  errors = EvaluateDepth(estimate, ground_truth, options);
  EXPECT_EQ(errors.scale, 1.0);
  EXPECT_NEAR(errors.relative_error, (0.5 + 0.5 + 2.0 / 6.0) / 3.0, 1e-12);
  EXPECT_NEAR(errors.psnr_db, 10.0 * std::log10(36.0 / 3.0), 1e-12);

  // Whole image: 12 valid pixels, ratios 1.5, 2, 2 and nine times 100: s = 100.
  options.crop_fraction = 1.0;
  options.align_scale = true;
  errors = EvaluateDepth(estimate, ground_truth, options);
  EXPECT_EQ(errors.num_pixels, 12);
  EXPECT_DOUBLE_EQ(errors.scale, 100.0);
  EXPECT_NEAR(errors.relative_error, (98.0 / 2.0 + 196.0 / 4.0 + 394.0 / 6.0) / 12.0, 1e-9);
  EXPECT_NEAR(errors.psnr_db,
              10.0 * std::log10(100.0 * 100.0 / ((98.0 * 98.0 + 196.0 * 196.0 + 394.0 * 394.0) / 12.0)),
              1e-9);
}

TEST(EvaluateDepthTest, EvenCountMedianAndPerfectEstimate) {
  const cv::Mat estimate(1, 4, CV_32FC1, cv::Scalar(1.0f));
  const cv::Mat ground_truth = (cv::Mat_<float>(1, 4) << 1.0f, 2.0f, 3.0f, 4.0f);
  const DepthErrors errors = EvaluateDepth(estimate, ground_truth, DepthMetricOptions());
  EXPECT_DOUBLE_EQ(errors.scale, 2.5);
  EXPECT_NEAR(errors.relative_error, (1.5 / 1.0 + 0.5 / 2.0 + 0.5 / 3.0 + 1.5 / 4.0) / 4.0, 1e-12);

  const DepthErrors perfect = EvaluateDepth(ground_truth * 0.5, ground_truth, DepthMetricOptions());
  EXPECT_DOUBLE_EQ(perfect.scale, 2.0);
  EXPECT_EQ(perfect.relative_error, 0.0);
  EXPECT_EQ(perfect.psnr_db, kInf);
}

TEST(EvaluateDepthTest, RejectsBadInput) {
  const cv::Mat ok(3, 3, CV_32FC1, cv::Scalar(1.0f));
  const cv::Mat invalid(3, 3, CV_32FC1, cv::Scalar(0.0f));
  EXPECT_THROW(EvaluateDepth(ok, invalid, DepthMetricOptions()), InputError);
  EXPECT_THROW(EvaluateDepth(ok, cv::Mat(3, 4, CV_32FC1, cv::Scalar(1.0f)), DepthMetricOptions()),
               InputError);
  DepthMetricOptions options;
  options.crop_fraction = 0.0;
  EXPECT_THROW(options.Check(), InputError);
  EXPECT_THROW(EvaluateDepth(ok, ok, options), InputError);
  options.crop_fraction = 1.01;
  EXPECT_THROW(options.Check(), InputError);
  options.crop_fraction = kNan;
  EXPECT_THROW(options.Check(), InputError);
  options.crop_fraction = 0.7;
  EXPECT_NO_THROW(options.Check());
  try {
    EvaluateDepth(ok, invalid, DepthMetricOptions());
  } catch (const InputError& error) {
    EXPECT_NE(std::string(error.what()).find("no pixel"), std::string::npos) << error.what();
  }
}

// -------------------------------------------------------- Umeyama and ATE

std::vector<Eigen::Vector3d> RandomPoints(int count, std::mt19937* random) {
  std::normal_distribution<double> normal;
  std::vector<Eigen::Vector3d> points(count);
  for (Eigen::Vector3d& p : points) p = Eigen::Vector3d(normal(*random), normal(*random), normal(*random));
  return points;
}

Sim3 KnownSim3(std::mt19937* random) {
  std::normal_distribution<double> normal;
  Sim3 sim3;
  sim3.scale = 2.5;
  sim3.rotation = Eigen::Quaterniond(normal(*random), normal(*random), normal(*random), normal(*random))
                      .normalized()
                      .toRotationMatrix();
  sim3.translation = Eigen::Vector3d(1.0, -2.0, 3.5);
  return sim3;
}

std::vector<Eigen::Vector3d> Apply(const Sim3& sim3, const std::vector<Eigen::Vector3d>& points) {
  std::vector<Eigen::Vector3d> out;
  for (const Eigen::Vector3d& p : points) out.push_back(sim3.scale * sim3.rotation * p + sim3.translation);
  return out;
}

TEST(UmeyamaTest, RecoversKnownSim3) {
  std::mt19937 random(42);
  for (int trial = 0; trial < 10; ++trial) {
    const Sim3 truth = KnownSim3(&random);
    const std::vector<Eigen::Vector3d> source = RandomPoints(20, &random);
    const std::vector<Eigen::Vector3d> target = Apply(truth, source);
    const Sim3 estimated = UmeyamaAlignment(source, target, true);
    EXPECT_NEAR(estimated.scale, 2.5, 1e-9);
    EXPECT_LT((estimated.rotation - truth.rotation).norm(), 1e-9);
    EXPECT_LT((estimated.translation - truth.translation).norm(), 1e-9);
    EXPECT_NEAR(estimated.rotation.determinant(), 1.0, 1e-12);
  }
}

TEST(UmeyamaTest, WithoutScaleAndMinimalPoints) {
  std::mt19937 random(3);
  Sim3 truth = KnownSim3(&random);
  truth.scale = 1.0;
  const std::vector<Eigen::Vector3d> source = RandomPoints(3, &random);
  const Sim3 estimated = UmeyamaAlignment(source, Apply(truth, source), false);
  EXPECT_EQ(estimated.scale, 1.0);
  EXPECT_LT((estimated.rotation - truth.rotation).norm(), 1e-9);
  EXPECT_LT((estimated.translation - truth.translation).norm(), 1e-9);
}

TEST(UmeyamaTest, NeverReturnsAReflection) {
  std::mt19937 random(5);
  const std::vector<Eigen::Vector3d> source = RandomPoints(10, &random);
  std::vector<Eigen::Vector3d> mirrored = source;
  for (Eigen::Vector3d& p : mirrored) p.x() = -p.x();
  const Sim3 estimated = UmeyamaAlignment(source, mirrored, true);
  EXPECT_NEAR(estimated.rotation.determinant(), 1.0, 1e-12);
  EXPECT_LT((estimated.rotation * estimated.rotation.transpose() - Eigen::Matrix3d::Identity()).norm(),
            1e-12);
}

TEST(UmeyamaTest, RejectsBadInput) {
  const std::vector<Eigen::Vector3d> two = {Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(1, 0, 0)};
  EXPECT_THROW(UmeyamaAlignment(two, two, true), InputError);
  const std::vector<Eigen::Vector3d> three = {Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(1, 0, 0),
                                              Eigen::Vector3d(0, 1, 0)};
  EXPECT_THROW(UmeyamaAlignment(three, two, true), InputError);
  const std::vector<Eigen::Vector3d> same(3, Eigen::Vector3d(1, 2, 3));
  EXPECT_THROW(UmeyamaAlignment(same, three, true), InputError);
  std::vector<Eigen::Vector3d> nan = three;
  nan[1].y() = kNan;
  EXPECT_THROW(UmeyamaAlignment(nan, three, true), InputError);
  EXPECT_THROW(AbsoluteTrajectoryRmse(two, two), InputError);
  EXPECT_THROW(AbsoluteTrajectoryRmse(three, two), InputError);
}

TEST(AteTest, TransformedTrajectoryHasZeroError) {
  std::mt19937 random(11);
  const Sim3 truth = KnownSim3(&random);
  const std::vector<Eigen::Vector3d> ground_truth = RandomPoints(30, &random);
  const std::vector<Eigen::Vector3d> estimate = Apply(truth, ground_truth);
  Sim3 alignment;
  EXPECT_LT(AbsoluteTrajectoryRmse(estimate, ground_truth, &alignment), 1e-9);
  // The alignment maps the estimate onto the ground truth: the inverse of truth.
  EXPECT_NEAR(alignment.scale, 1.0 / 2.5, 1e-9);
  EXPECT_LT((alignment.rotation - truth.rotation.transpose()).norm(), 1e-9);

  // A straight-line trajectory (rotation about the line undetermined) still aligns.
  std::vector<Eigen::Vector3d> line;
  for (int i = 0; i < 5; ++i) line.push_back(Eigen::Vector3d(0.1 * i, 0.2 * i, -0.05 * i));
  EXPECT_LT(AbsoluteTrajectoryRmse(Apply(truth, line), line), 1e-9);
}

TEST(AteTest, PerturbedSquareMatchesHandComputedValue) {
  // Ground truth: the corners (+-1, +-1, 0) of a square, shifted. Estimate:
  // the same corners with z offsets d*x*y (d = 1), uncorrelated with x and y,
  // so no rotation or translation is needed; the scale is
  // trace(Sigma)/var(est) = 2 / (2 + d^2) = 2/3 and each residual is
  // (1 - c) p - c n: |r|^2 = 2 (1/3)^2 + (2/3)^2 = 2/3.
  const Eigen::Vector3d offset(5.0, -3.0, 2.0);
  std::vector<Eigen::Vector3d> ground_truth;
  std::vector<Eigen::Vector3d> estimate;
  for (double x : {-1.0, 1.0}) {
    for (double y : {-1.0, 1.0}) {
      ground_truth.push_back(Eigen::Vector3d(x, y, 0.0) + offset);
      estimate.push_back(Eigen::Vector3d(x, y, x * y) + offset);
    }
  }
  Sim3 alignment;
  EXPECT_NEAR(AbsoluteTrajectoryRmse(estimate, ground_truth, &alignment), std::sqrt(2.0 / 3.0), 1e-12);
  EXPECT_NEAR(alignment.scale, 2.0 / 3.0, 1e-12);
  EXPECT_LT((alignment.rotation - Eigen::Matrix3d::Identity()).norm(), 1e-12);
}

}  // namespace
}  // namespace deblur_sr_mvs
