// The imaging model and the data agree: Psi_t built from the ground-truth
// depth and poses, applied to the ground-truth sharp HR frame, reproduces the
// synthesizer's blurred LR frame (the synthesizer renders every sub-frame from
// the scene instead; eq:blurOperator approximates that by warping I_t), with
// a global shutter and with a rolling shutter (readout 0.8 of the frame
// interval, docs/file_formats.md#rolling-shutter). Adaptive M (about one
// virtual camera per HR pixel of blur) costs at most 0.1 dB of that agreement
// against the paper's fixed M = 50.
#include <cstdio>
#include <cstdlib>
#include <string>

#include <opencv2/imgproc.hpp>

#include <unistd.h>

#include <filesystem>

#include <gtest/gtest.h>

#include "deblur_sr_mvs/core/estimation/frame_structure.h"
#include "deblur_sr_mvs/core/evaluation/metrics.h"
#include "deblur_sr_mvs/core/imaging/capture_operator.h"
#include "deblur_sr_mvs/core/imaging/image_ops.h"
#include "deblur_sr_mvs/core/io/sequence_io.h"

namespace deblur_sr_mvs {
namespace {

class ModelAgreement : public testing::TestWithParam<double> {};

TEST_P(ModelAgreement, CaptureOperatorReproducesSynthesizedBlur) {
  const double readout_ratio = GetParam();
  const std::string folder = testing::TempDir() + "/dsm_model_agreement_" + std::to_string(::getpid());
  const std::string command = std::string(DSM_TOOL_DIR) + "/synthesize_sequence --scene " + DSM_SOURCE_DIR +
                              "/data/middlebury/Dolls --output " + folder + " --frames 4 --readout-ratio " +
                              std::to_string(readout_ratio) + " > /dev/null";
  ASSERT_EQ(std::system(command.c_str()), 0);
  const Sequence sequence = ReadSequence(folder, true);
  std::filesystem::remove_all(folder);
  ASSERT_TRUE(sequence.ground_truth.has_value());
  const int scale = sequence.ground_truth->calibration.camera.width / sequence.calibration.camera.width;
  ASSERT_EQ(scale, 2);
  ASSERT_EQ(sequence.readout_time > 0.0, readout_ratio > 0.0);

  std::vector<FrameStructure> frames(sequence.frames.size());
  for (size_t t = 0; t < frames.size(); ++t) {
    frames[t].stamp = sequence.frames[t].stamp;
    frames[t].exposure = sequence.frames[t].exposure;
    frames[t].readout_time = sequence.readout_time;
    frames[t].T_world_cam = sequence.ground_truth->poses[t].T_world_cam;
    frames[t].depth_hr = sequence.ground_truth->depth[t];
  }
  CaptureOperatorOptions options;  // M = 50, fixed
  options.scale = scale;
  CaptureOperatorOptions adaptive = options;  // the estimator's default: M = 50 is the cap
  adaptive.adaptive_samples = true;
  for (int t = 0; t < static_cast<int>(frames.size()); ++t) {
    const CaptureGeometry geometry =
        MakeCaptureGeometry(frames, sequence.ground_truth->calibration.camera, t, t);
    const CaptureOperator op = BuildCaptureOperator(geometry, options);
    const CaptureOperator adaptive_op = BuildCaptureOperator(geometry, adaptive);
    cv::Mat predicted, adaptive_predicted;
    op.Apply(ToFloat01(sequence.ground_truth->latent[t]), &predicted);
    adaptive_op.Apply(ToFloat01(sequence.ground_truth->latent[t]), &adaptive_predicted);
    const cv::Mat predicted8 = ToImage8(predicted);

    // Away from image borders (samples must stay inside the frame) and from
    // depth discontinuities (occlusions), dilated by the blur length.
    cv::Mat mask(op.lr_size(), CV_8UC1);
    for (int i = 0; i < mask.rows * mask.cols; ++i) {
      mask.ptr<uchar>()[i] = op.coverage()[i] >= 1.0f ? 255 : 0;
    }
    cv::Mat log_depth, gx, gy, magnitude, edges;
    cv::log(sequence.ground_truth->depth[t], log_depth);
    cv::Sobel(log_depth, gx, CV_32F, 1, 0);
    cv::Sobel(log_depth, gy, CV_32F, 0, 1);
    cv::magnitude(gx, gy, magnitude);
    cv::threshold(magnitude, edges, 0.2, 255, cv::THRESH_BINARY);  // >2.5 % depth step per px
    edges.convertTo(edges, CV_8U);
    cv::dilate(edges, edges, cv::Mat::ones(5, 41, CV_8U));  // the blur is up to ~20 HR px along x
    cv::resize(edges, edges, op.lr_size(), 0, 0, cv::INTER_NEAREST);
    mask.setTo(0, edges);
    const int border = 4;
    mask.rowRange(0, border).setTo(0);
    mask.rowRange(mask.rows - border, mask.rows).setTo(0);
    mask.colRange(0, border).setTo(0);
    mask.colRange(mask.cols - border, mask.cols).setTo(0);
    const double fraction = cv::countNonZero(mask) / double(mask.total());
    const double psnr = Psnr(predicted8, sequence.images[t], 255.0, mask);
    const double psnr_all = Psnr(predicted8, sequence.images[t], 255.0);
    const double adaptive_psnr = Psnr(ToImage8(adaptive_predicted), sequence.images[t], 255.0, mask);
    std::printf(
        "readout %.1f, frame %d: Psi_t(gt latent) vs blurred input: %.2f dB on %.0f%% of pixels (%.2f dB "
        "on all); adaptive M = %d (blur %.1f HR px): %.2f dB\n",
        readout_ratio, t, psnr, 100.0 * fraction, psnr_all, CaptureSamples(geometry, adaptive),
        BlurLengthHr(geometry, scale), adaptive_psnr);
    EXPECT_GE(psnr, 30.0) << "frame " << t;
    EXPECT_GT(fraction, 0.4);
    EXPECT_GE(adaptive_psnr, psnr - 0.1) << "frame " << t;
  }
}

// 0: global shutter; 0.8: the rolling shutter of issue 12's target.
INSTANTIATE_TEST_SUITE_P(Shutters, ModelAgreement, testing::Values(0.0, 0.8));

}  // namespace
}  // namespace deblur_sr_mvs
