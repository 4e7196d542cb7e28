// report.json of estimate_sequence: the parameters, the energy after every
// stage, the stage timings and the solver's notes (an undone iteration's
// energies may be NaN: they are written as null).
#pragma once

#include <string>

#include "deblur_sr_mvs/core/estimation/estimator.h"
#include "report_json.h"

namespace deblur_sr_mvs {

inline Json EstimateReportJson(const EstimatorOptions& options, const std::string& input,
                               const EstimatorResult& result, double wall_seconds, double peak_memory_mib) {
  Json report;
  report["input"] = input;
  report["parameters"] = {{"mode", ToString(options.mode)},
                          {"scale", options.scale},
                          {"iterations", options.max_iterations},
                          {"samples", options.samples},
                          {"lambda_s", JsonNumber(options.lambda_s)},
                          {"lambda_d", JsonNumber(options.structure.lambda_d)},
                          {"lambda_i", JsonNumber(options.image.lambda_i)},
                          {"neighbour_radius", options.neighbour_radius},
                          {"pose_neighbour_radius", options.pose_neighbour_radius},
                          {"update_poses", options.update_poses},
                          {"structure_matching", ToString(options.structure_matching)},
                          {"gain_compensation", options.gain_compensation},
                          {"threads", options.num_threads}};
  Json energies = Json::array();
  for (const EnergyRecord& e : result.energies) {
    energies.push_back({{"iteration", e.iteration},
                        {"stage", e.stage},
                        {"total", JsonNumber(e.total)},
                        {"matching", JsonNumber(e.matching)},
                        {"self_consistency", JsonNumber(e.self_consistency)},
                        {"image_tv", JsonNumber(e.image_tv)},
                        {"depth_tv", JsonNumber(e.depth_tv)}});
  }
  report["energies"] = energies;
  Json stage_seconds = Json::object();
  for (const StageTiming& timing : result.timings) stage_seconds[timing.stage] = JsonNumber(timing.seconds);
  report["stage_seconds"] = stage_seconds;
  report["wall_seconds"] = JsonNumber(wall_seconds);
  report["peak_memory_mib"] = JsonNumber(peak_memory_mib);
  std::string summary = result.initializer_summary;  // one line, its parts separated by ';'
  for (char& c : summary) {
    if (c == '\n') c = ';';
  }
  report["initializer"] = summary;
  report["solver_notes"] = result.notes;
  report["monocular_scale"] =
      result.depth_observable
          ? "arbitrary: world = first camera, median scene depth 1 unit "
            "(docs/file_formats.md#monocular-scale)"
          : "no parallax: depth not observable; world = first camera, every camera at its centre "
            "(docs/file_formats.md#no-parallax)";
  Json gains = Json::array();
  for (double gain : result.frame_gains) gains.push_back(JsonNumber(gain));
  report["frame_gains"] = gains;
  // The noise level used (given, or estimated from the window's frames) in
  // 8-bit gray levels, and the image TV weight it gave.
  report["noise"] = {{"sigma_gray_levels", JsonNumber(result.noise_sigma * 255.0)},
                     {"estimated", options.noise_sigma < 0.0},
                     {"lambda_i", JsonNumber(result.image_lambda_i)}};
  // The work of the image solves (ImageUpdateStats, summed over the window's
  // updates): operator passes count streams over one operator's rows.
  report["image_work"] = {{"reweightings", result.image_work.reweightings},
                          {"cg_steps", result.image_work.cg_steps},
                          {"operator_passes", static_cast<double>(result.image_work.operator_passes)}};
  return report;
}

}  // namespace deblur_sr_mvs
