// Test support: sequences made by the synthesize_sequence tool (with ground
// truth), the estimator's input from a sequence, PSNR against the ground truth.
#pragma once

#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <string>

#include <gtest/gtest.h>

#include "deblur_sr_mvs/core/estimation/estimator.h"
#include "deblur_sr_mvs/core/estimation/stream.h"
#include "deblur_sr_mvs/core/evaluation/metrics.h"
#include "deblur_sr_mvs/core/imaging/image_ops.h"
#include "deblur_sr_mvs/core/io/sequence_io.h"

namespace deblur_sr_mvs {

// `scene`: a folder under data/middlebury; `flags`: further synthesize_sequence
// flags (e.g. "--frames 6 --path rotate"). `tag` keeps the folders of one
// binary apart (ctest runs tests in parallel).
inline Sequence SynthesizedSequence(const std::string& tag, const std::string& scene,
                                    const std::string& flags) {
  const std::string folder = testing::TempDir() + "/dsm_" + tag + "_" + std::to_string(::getpid());
  const std::string command = std::string(DSM_TOOL_DIR) + "/synthesize_sequence --scene " + DSM_SOURCE_DIR +
                              "/data/middlebury/" + scene + " --output " + folder + " " + flags +
                              " > /dev/null";
  EXPECT_EQ(std::system(command.c_str()), 0) << command;
  Sequence read = ReadSequence(folder, true);
  std::filesystem::remove_all(folder);
  return read;
}

inline EstimatorInput InputOf(const Sequence& sequence) {
  EstimatorInput input;
  input.camera = sequence.calibration.camera;
  input.frames = sequence.frames;
  input.readout_time = sequence.readout_time;
  for (const cv::Mat& image : sequence.images) input.images.push_back(ToFloat01(image));
  return input;
}

// Mean PSNR (dB, 8-bit) of float [0, 1] estimates against 8-bit truths.
inline double MeanPsnr(const std::vector<cv::Mat>& estimates01, const std::vector<cv::Mat>& truth8) {
  double sum = 0.0;
  for (size_t t = 0; t < estimates01.size(); ++t) sum += Psnr(ToImage8(estimates01[t]), truth8[t], 255.0);
  return sum / estimates01.size();
}

// Mean depth rel. error (per-frame median scale, 70 % centre crop).
inline double MeanDepthRel(const std::vector<cv::Mat>& estimate, const std::vector<cv::Mat>& truth) {
  DepthMetricOptions options;
  options.crop_fraction = 0.7;
  double sum = 0.0;
  for (size_t t = 0; t < estimate.size(); ++t)
    sum += EvaluateDepth(estimate[t], truth[t], options).relative_error;
  return sum / estimate.size();
}

// The windows a FrameWindower cuts from these frames: frame t gets id
// first_id + t and caller stamp t x 33 ms.
inline std::vector<StreamWindow> StreamWindowsOf(const std::vector<cv::Mat>& images8,
                                                 const std::vector<FrameRecord>& frames,
                                                 const StreamOptions& stream_options, uint64_t first_id) {
  FrameWindower windower(stream_options);
  std::vector<StreamWindow> windows;
  for (size_t t = 0; t < images8.size(); ++t) {
    StreamFrame frame;
    frame.id = first_id + t;
    frame.stamp_ns = static_cast<int64_t>(t) * 33000000;
    frame.stamp_close = frames[t].stamp;
    frame.exposure = frames[t].exposure;
    frame.image = ToFloat01(images8[t]);
    for (StreamWindow& window : windower.Add(frame)) windows.push_back(std::move(window));
  }
  return windows;
}

// Cheap estimator settings for the stream tests (M 20, one iteration).
inline EstimatorOptions FastEstimatorOptions() {
  EstimatorOptions options;
  options.samples = 20;
  options.max_iterations = 1;
  return options;
}

}  // namespace deblur_sr_mvs
