#include "deblur_sr_mvs/core/io/result_io.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <system_error>

#include "deblur_sr_mvs/core/common/text.h"
#include "deblur_sr_mvs/core/imaging/image_ops.h"

namespace deblur_sr_mvs {
namespace {

namespace fs = std::filesystem;

constexpr double kStampTolerance = 1e-6;  // s, as sequence_io checks gt poses

[[noreturn]] void Fail(const std::string& path, const std::string& message) {
  throw InputError(path + ": " + message);
}

std::string StampText(double stamp) {
  char buffer[64];
  std::snprintf(buffer, sizeof(buffer), "%.9g", stamp);
  return buffer;
}

std::string LatentPath(const fs::path& root, int index) {
  return (root / "latent" / (FrameStem(index) + ".png")).string();
}
std::string DepthPath(const fs::path& root, int index) {
  return (root / "depth" / (FrameStem(index) + ".tiff")).string();
}
std::string DepthColorPath(const fs::path& root, int index) {
  return (root / "depth_color" / (FrameStem(index) + ".png")).string();
}

// Checks shared by the writer and the reader; `where` names the file (reader)
// or the folder being written (writer) for each kind of entry.
void CheckLatent(const std::string& where, const cv::Mat& latent, const PinholeCamera& camera,
                 const std::string& camera_path, int first_channels) {
  if (latent.empty()) Fail(where, "latent image is empty");
  if (latent.depth() != CV_8U || (latent.channels() != 1 && latent.channels() != 3)) {
    Fail(where, "latent image must be 8-bit gray or colour (convert with ToImage8)");
  }
  if (latent.cols != camera.width || latent.rows != camera.height) {
    Fail(where, "latent image is " + SizeText(latent.cols, latent.rows) + " but " + camera_path + " says " +
                    SizeText(camera.width, camera.height));
  }
  if (first_channels > 0 && latent.channels() != first_channels) {
    Fail(where, "latent image has " + std::to_string(latent.channels()) + " channel(s) but frame 0 has " +
                    std::to_string(first_channels));
  }
}

void CheckDepth(const std::string& where, const cv::Mat& depth, const PinholeCamera& camera,
                const std::string& camera_path) {
  if (depth.type() != CV_32FC1) Fail(where, "depth must be float32 single-channel (32FC1)");
  if (depth.cols != camera.width || depth.rows != camera.height) {
    Fail(where, "depth is " + SizeText(depth.cols, depth.rows) + " but " + camera_path + " says " +
                    SizeText(camera.width, camera.height));
  }
}

void CheckPoses(const std::string& where, const std::vector<StampedPose>& poses,
                const std::vector<FrameRecord>& frames) {
  if (poses.size() != frames.size()) {
    Fail(where, std::to_string(poses.size()) + " poses for " + std::to_string(frames.size()) +
                    " frames (one pose per frame)");
  }
  for (std::size_t i = 0; i < poses.size(); ++i) {
    if (!(std::abs(poses[i].stamp - frames[i].stamp) <= kStampTolerance)) {
      Fail(where, "pose " + std::to_string(i) + " has stamp " + StampText(poses[i].stamp) + " but frame " +
                      std::to_string(frames[i].index) + " has stamp " + StampText(frames[i].stamp) +
                      " (tolerance 1e-6 s)");
    }
  }
}

// One colour scale for the whole sequence: 2nd-98th percentiles of the valid
// depths of all frames (sampled, so memory stays bounded on long sequences).
void PooledDepthRange(const std::vector<cv::Mat>& depths, double* min_depth, double* max_depth) {
  constexpr std::size_t kMaxSamples = 2000000;
  std::size_t total = 0;
  for (const cv::Mat& depth : depths) total += depth.total();
  const std::size_t stride = std::max<std::size_t>(1, total / kMaxSamples);
  std::vector<float> values;
  values.reserve(std::min(total, kMaxSamples + depths.size()));
  for (const cv::Mat& depth : depths) {
    std::size_t counter = 0;
    for (int y = 0; y < depth.rows; ++y) {
      const float* row = depth.ptr<float>(y);
      for (int x = 0; x < depth.cols; ++x, ++counter) {
        if (counter % stride != 0) continue;
        if (row[x] > 0.0f && std::isfinite(row[x])) values.push_back(row[x]);
      }
    }
  }
  *min_depth = 0.0;
  *max_depth = 0.0;
  if (values.empty()) return;  // ColorizeDepth then draws every frame black
  const std::size_t low = values.size() * 2 / 100;
  const std::size_t high = values.size() * 98 / 100;
  std::nth_element(values.begin(), values.begin() + low, values.end());
  *min_depth = values[low];
  std::nth_element(values.begin(), values.begin() + high, values.end());
  *max_depth = values[high];
  if (!(*max_depth > *min_depth)) *max_depth = *min_depth * (1.0 + 1e-6) + 1e-9;
}

void WriteText(const std::string& path, const std::string& content) {
  std::error_code error;
  fs::create_directories(fs::path(path).parent_path(), error);
  if (error) Fail(path, "cannot create folder: " + error.message());
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  if (!out) Fail(path, "cannot open file for writing");
  out << content;
  out.close();
  if (!out) Fail(path, "write error");
}

// A folder rewritten by a method without depth or poses must not keep those
// of an earlier run, or ReadResult would pair them with the new images. Only
// the files this format names are removed.
void RemoveStaleEntries(const fs::path& root, const SequenceResult& result) {
  std::error_code error;
  if (!result.HasPoses()) fs::remove(root / "poses.txt", error);
  if (result.HasDepth()) return;
  for (const char* sub : {"depth", "depth_color"}) {
    const fs::path folder = root / sub;
    if (!fs::is_directory(folder, error)) continue;
    std::vector<fs::path> stale;
    for (const fs::directory_entry& entry : fs::directory_iterator(folder, error)) {
      const std::string stem = entry.path().stem().string();
      const std::string extension = entry.path().extension().string();
      const bool numbered = stem.size() == 6 && std::all_of(stem.begin(), stem.end(), [](unsigned char c) {
                              return std::isdigit(c) != 0;
                            });
      if (numbered && (extension == ".tiff" || extension == ".png")) stale.push_back(entry.path());
    }
    for (const fs::path& path : stale) fs::remove(path, error);
    fs::remove(folder, error);  // only succeeds when nothing else is left in it
  }
}

}  // namespace

void WriteResult(const std::string& folder, const SequenceResult& result) {
  const fs::path root(folder);
  const PinholeCamera& camera = result.calibration.camera;
  const std::string camera_path = (root / "camera.yaml").string();
  const std::string problem = camera.Problem();
  if (!problem.empty()) Fail(camera_path, "cannot write the result: " + problem);
  const std::size_t count = result.frames.size();
  if (count == 0) Fail(folder, "cannot write a result without frames");
  if (result.latent.size() != count) {
    Fail(folder, "cannot write " + std::to_string(result.latent.size()) + " latent images for " +
                     std::to_string(count) + " frames");
  }
  if (result.HasDepth() && result.depth.size() != count) {
    Fail(folder, "cannot write " + std::to_string(result.depth.size()) + " depth maps for " +
                     std::to_string(count) + " frames (give one per frame or none)");
  }
  for (std::size_t i = 0; i < count; ++i) {
    const int index = result.frames[i].index;
    CheckLatent(LatentPath(root, index), result.latent[i], camera, camera_path,
                i == 0 ? 0 : result.latent[0].channels());
    if (result.HasDepth()) CheckDepth(DepthPath(root, index), result.depth[i], camera, camera_path);
  }
  if (result.HasPoses()) CheckPoses((root / "poses.txt").string(), result.poses, result.frames);

  std::error_code error;
  fs::create_directories(root / "latent", error);
  if (error) Fail(folder, "cannot create folder: " + error.message());
  RemoveStaleEntries(root, result);

  WriteCameraYaml(camera_path, result.calibration);
  WriteFramesCsv((root / "frames.csv").string(), result.frames);
  for (std::size_t i = 0; i < count; ++i) {
    WriteImage(LatentPath(root, result.frames[i].index), result.latent[i]);
  }
  if (result.HasDepth()) {
    double min_depth = 0.0;
    double max_depth = 0.0;
    PooledDepthRange(result.depth, &min_depth, &max_depth);
    for (std::size_t i = 0; i < count; ++i) {
      const int index = result.frames[i].index;
      WriteDepthTiff(DepthPath(root, index), result.depth[i]);
      WriteImage(DepthColorPath(root, index), ColorizeDepth(result.depth[i], min_depth, max_depth));
    }
  }
  if (result.HasPoses()) WriteTumTrajectory((root / "poses.txt").string(), result.poses);
  std::string report = result.report_json;
  const bool blank = report.find_first_not_of(" \t\r\n") == std::string::npos;
  if (blank) report = "{}";
  if (report.back() != '\n') report += '\n';
  WriteText((root / "report.json").string(), report);
}

SequenceResult ReadResult(const std::string& folder) {
  const fs::path root(folder);
  std::error_code error;
  if (!fs::is_directory(root, error)) Fail(folder, "result folder not found");

  SequenceResult result;
  const std::string camera_path = (root / "camera.yaml").string();
  result.calibration = ReadCameraYaml(camera_path);
  const PinholeCamera& camera = result.calibration.camera;
  result.frames = ReadFramesCsv((root / "frames.csv").string());
  const std::size_t count = result.frames.size();

  result.latent.reserve(count);
  for (const FrameRecord& frame : result.frames) {
    const std::string path = LatentPath(root, frame.index);
    cv::Mat latent = ReadImage8(path);
    CheckLatent(path, latent, camera, camera_path,
                result.latent.empty() ? 0 : result.latent.front().channels());
    result.latent.push_back(std::move(latent));
  }

  // depth/ and poses.txt are optional as a whole, but once present they must
  // be complete: a missing file is an error, not a silently shorter result.
  const fs::path depth_root = root / "depth";
  if (fs::exists(depth_root, error)) {
    if (!fs::is_directory(depth_root, error)) Fail(depth_root.string(), "is not a folder");
    result.depth.reserve(count);
    for (const FrameRecord& frame : result.frames) {
      const std::string path = DepthPath(root, frame.index);
      cv::Mat depth = ReadDepthTiff(path);
      CheckDepth(path, depth, camera, camera_path);
      result.depth.push_back(std::move(depth));
    }
  }
  const std::string poses_path = (root / "poses.txt").string();
  if (fs::exists(poses_path, error)) {
    result.poses = ReadTumTrajectory(poses_path);
    CheckPoses(poses_path, result.poses, result.frames);
  }
  const std::string report_path = (root / "report.json").string();
  if (fs::exists(report_path, error)) result.report_json = ReadTextFile(report_path);
  return result;
}

}  // namespace deblur_sr_mvs
