// Runs a sequence folder through the streaming estimator as the node does
// (FrameWindower windows, StreamEstimator, the node's estimator defaults:
// the published depth re-swept and made consistent), without ROS, and writes
// the frames each window publishes as a result folder for evaluate_sequence,
// with each window's wall time and stage times in report.json. A benchmark
// of the node's accuracy and work per window (docs/tools.md#benchmark_stream).
// Usage: benchmark_stream --input SEQ --output OUT [--window-size N]
//        [--window-overlap K] [--threads T] [--no-depth-sweep]
//        [--depth-consistency-radius R] [--iterations N]
//        [--continued-iterations N] [--continued-recentred-passes N]
//        [--recentred-passes-on-held-frames] [--quiet]
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "deblur_sr_mvs/core/estimation/stream.h"
#include "deblur_sr_mvs/core/imaging/image_ops.h"
#include "deblur_sr_mvs/core/io/result_io.h"
#include "deblur_sr_mvs/core/io/sequence_io.h"
#include "tool_main.h"

namespace dsm = deblur_sr_mvs;

namespace {

struct StreamRun {
  dsm::SequenceResult result;
  nlohmann::json windows = nlohmann::json::array();
  double seconds = 0.0;
};

// The frame of `sequence` with the given index as the node receives it
// (id = index + 1; the stamp is the shutter close, frames.csv's).
dsm::StreamFrame FrameOf(const dsm::Sequence& sequence, size_t index) {
  dsm::StreamFrame frame;
  frame.id = index + 1;
  frame.stamp_ns = static_cast<int64_t>(sequence.frames[index].stamp * 1e9);
  frame.stamp_close = sequence.frames[index].stamp;
  frame.exposure = sequence.frames[index].exposure;
  frame.readout_time = sequence.readout_time;
  frame.image = dsm::ToFloat01(sequence.images[index]);
  return frame;
}

// Adds the frames `estimate` publishes (first_new on) to `run`.
void Publish(const dsm::Sequence& sequence, const dsm::WindowEstimate& estimate, StreamRun* run) {
  const dsm::EstimatorResult& result = estimate.result;
  if (run->result.latent.empty()) {
    run->result.calibration = dsm::CameraCalibration::FromCamera(result.camera_hr, sequence.calibration.camera_name);
  }
  for (size_t k = estimate.first_new; k < estimate.ids.size(); ++k) {
    const dsm::FrameRecord& record = sequence.frames[estimate.ids[k] - 1];
    run->result.frames.push_back(record);
    run->result.latent.push_back(dsm::ToImage8(result.latent[k]));
    run->result.depth.push_back(result.depth[k]);
    run->result.poses.push_back(dsm::StampedPose{record.stamp, result.T_world_cam[k]});
  }
}

// One window through the stream: its time and stages into the run's
// report, its new frames into the run's result.
void ProcessWindow(const dsm::Sequence& sequence, const dsm::StreamWindow& window, bool quiet,
                   dsm::StreamEstimator* stream, StreamRun* run) {
  const auto begin = std::chrono::steady_clock::now();
  const dsm::WindowEstimate estimate = stream->Process(window, sequence.calibration.camera);
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - begin).count();
  run->seconds += seconds;
  nlohmann::json stages = nlohmann::json::object();
  for (const dsm::StageTiming& timing : estimate.result.timings) stages[timing.stage] = timing.seconds;
  run->windows.push_back({{"first_frame", window.front().id - 1},
                          {"last_frame", window.back().id - 1},
                          {"seconds", seconds},
                          {"continued", estimate.continued},
                          {"note", estimate.note},
                          {"stage_seconds", stages}});
  if (!quiet) {
    std::printf("window %llu-%llu: %.2f s%s\n", static_cast<unsigned long long>(window.front().id - 1),
                static_cast<unsigned long long>(window.back().id - 1), seconds,
                estimate.continued ? " (continued)" : "");
  }
  Publish(sequence, estimate, run);
}

int Run(int argc, char** argv) {
  dsm::ToolCommandLine cli("benchmark_stream",
                           "Runs a sequence folder through the node's streaming estimator (windows, defaults) "
                           "without ROS; writes the published frames as a result folder.");
  std::string input, output;
  dsm::StreamOptions stream_options;
  dsm::EstimatorOptions options = dsm::StreamDefaultEstimatorOptions();  // the node's, without its time cap
  bool quiet = false;
  cli.add_option("--input", input, "sequence folder (camera.yaml, frames.csv, images/)")->required();
  cli.add_option("--output", output, "result folder to write")->required();
  cli.add_option("--window-size", stream_options.window_size, "frames per window (default 6)")
      ->check(dsm::FlagInt(3, 30));
  cli.add_option("--window-overlap", stream_options.window_overlap,
                 "frames shared by consecutive windows (default 2)")
      ->check(dsm::FlagInt(2, 29));
  cli.add_option("--threads", options.num_threads, "OpenMP threads, 0 = all cores")->check(dsm::FlagInt(0, 1024));
  cli.add_flag("--depth-sweep,!--no-depth-sweep", options.depth_sweep.on_output,
               "re-sweep the published depth over the restored images (default on, as the node)");
  cli.add_option("--depth-consistency-radius", options.depth_consistency.radius,
                 "published depth made consistent with the frames up to N away (default 2, as the node; 0: off)")
      ->check(dsm::FlagInt(0, 10));
  cli.add_option("--iterations", options.max_iterations,
                 "joint iterations per window (default 3, as the node)")
      ->check(dsm::FlagInt(0, 100));
  cli.add_option("--continued-iterations", options.continued_max_iterations,
                 "joint iterations in a window that continues the previous one (default: --iterations)")
      ->check(dsm::FlagInt(0, 100));
  cli.add_option("--continued-recentred-passes", options.continued_recentred_depth_passes,
                 "re-centred depth passes in a continued window (default 0: as in any window)")
      ->check(dsm::FlagInt(0, 10));
  cli.add_flag(
      "--recentred-passes-on-held-frames", options.recentred_passes_on_held_frames,
      "the re-centred depth passes also update the frames a continued window shares with the previous "
      "one (default off)");
  cli.add_flag("--quiet", quiet, "no per-window lines on stdout");
  if (!cli.Parse(argc, argv)) return 0;
  stream_options.Check();
  options.Check();
  const dsm::Sequence sequence = dsm::ReadSequence(input, false);
  dsm::FrameWindower windower(stream_options);
  dsm::StreamEstimator stream(options);
  stream.SetWindowOverlap(stream_options.window_overlap);
  StreamRun run;
  for (size_t i = 0; i < sequence.images.size(); ++i) {
    for (const dsm::StreamWindow& window : windower.Add(FrameOf(sequence, i))) {
      ProcessWindow(sequence, window, quiet, &stream, &run);
    }
  }
  if (run.result.latent.size() != sequence.images.size()) {
    throw dsm::InputError("the windows published " + std::to_string(run.result.latent.size()) + " of " +
                          std::to_string(sequence.images.size()) +
                          " frames (the last frames fill no window of this size and overlap)");
  }
  const nlohmann::json report = {{"window_size", stream_options.window_size},
                                 {"window_overlap", stream_options.window_overlap},
                                 {"depth_sweep", options.depth_sweep.on_output},
                                 {"depth_consistency_radius", options.depth_consistency.radius},
                                 {"wall_seconds", run.seconds},
                                 {"windows", run.windows}};
  run.result.report_json = report.dump(2);
  dsm::WriteResult(output, run.result);
  if (!quiet) std::printf("%zu frames in %zu windows, %.2f s\n", run.result.latent.size(), run.windows.size(), run.seconds);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  return deblur_sr_mvs::ToolMain("benchmark_stream", Run, argc, argv);
}
