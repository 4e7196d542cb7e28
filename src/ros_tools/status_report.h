// report.json of bag_to_result: the estimator node's windows, from its status
// messages (energies of an undone iteration may be NaN: they become null).
#pragma once

#include <string>
#include <vector>

#include "deblur_sr_mvs/EstimatorStatus.h"
#include "report_json.h"

namespace deblur_sr_mvs {

inline Json StatusReportJson(const std::vector<EstimatorStatusConstPtr>& statuses) {
  Json report;
  report["source"] = "deblur_sr_mvs estimator node (bag_to_result)";
  Json windows = Json::array();
  for (const EstimatorStatusConstPtr& status : statuses) {
    const EstimatorStatus& s = *status;
    Json window;
    window["window_index"] = s.window_index;
    window["success"] = static_cast<bool>(s.success);
    window["continued"] = static_cast<bool>(s.continued);
    window["frames"] = s.frame_stamps.size();
    window["first_new"] = s.first_new;
    window["processing_seconds"] = JsonNumber(s.processing_seconds);
    window["latency_seconds"] = JsonNumber(s.latency_seconds);
    window["message"] = s.message;
    Json energies = Json::array();
    for (const double energy : s.energies) energies.push_back(JsonNumber(energy));
    window["energies"] = energies;
    Json stages = Json::object();
    for (size_t k = 0; k < s.stage_names.size() && k < s.stage_seconds.size(); ++k) {
      stages[s.stage_names[k]] = JsonNumber(s.stage_seconds[k]);
    }
    window["stages"] = stages;
    window["exposure_source"] = s.exposure_source;
    Json exposures = Json::array();
    for (const double exposure : s.frame_exposures) exposures.push_back(JsonNumber(exposure));
    window["frame_exposures"] = exposures;
    window["exposure_fraction"] = JsonNumber(s.exposure_fraction);
    Json gains = Json::array();
    for (const double gain : s.frame_gains) gains.push_back(JsonNumber(gain));
    window["frame_gains"] = gains;
    windows.push_back(window);
  }
  report["windows"] = windows;
  if (!statuses.empty()) {
    const EstimatorStatus& last = *statuses.back();
    report["frames_received"] = last.frames_received;
    report["frames_rejected"] = last.frames_rejected;
    report["frames_published"] = last.frames_published;
    report["windows_dropped"] = last.windows_dropped;
    report["windows_failed"] = last.windows_failed;
    report["exposures_rejected"] = last.exposures_rejected;
    report["scale_note"] = last.scale_note;
  }
  return report;
}

}  // namespace deblur_sr_mvs
