#include "deblur_sr_mvs/core/io/sequence_io.h"
#include "deblur_sr_mvs/core/common/text.h"

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <sstream>
#include <system_error>

#include <yaml-cpp/yaml.h>
#include <opencv2/imgcodecs.hpp>

namespace deblur_sr_mvs {
namespace {

namespace fs = std::filesystem;

// ------------------------------------------------------------------ helpers

[[noreturn]] void Fail(const std::string& path, const std::string& message) {
  throw InputError(path + ": " + message);
}

[[noreturn]] void FailAt(const std::string& path, int line, const std::string& message) {
  throw InputError(path + ":" + std::to_string(line) + ": " + message);
}

// Shortest text that parses back to exactly `value` (locale independent).
std::string FormatDouble(double value) {
  char buffer[64];
  const std::to_chars_result result = std::to_chars(buffer, buffer + sizeof(buffer), value);
  return std::string(buffer, result.ptr);
}

// Short form for messages: 0.3 - 0.25 reads 0.05, not 0.04999999999999999.
std::string MessageNumber(double value) {
  char buffer[64];
  std::snprintf(buffer, sizeof(buffer), "%.9g", value);
  return buffer;
}

// User text for messages: bounded length, non-printable bytes as '?', so
// that binary garbage still gives a one-line message.
std::string Printable(const std::string& text, std::size_t max_length) {
  std::string out;
  for (std::size_t i = 0; i < text.size() && i < max_length; ++i) {
    const unsigned char c = static_cast<unsigned char>(text[i]);
    out += (c >= 0x20 && c < 0x7f) ? static_cast<char>(c) : '?';
  }
  if (text.size() > max_length) out += "...";
  return out;
}

// Quotes user text in messages (see Printable).
std::string Quote(const std::string& text) {
  return "'" + Printable(text, 40) + "'";
}

std::string Trim(const std::string& text) {
  const char* kSpace = " \t\r\n\f\v";
  const std::size_t begin = text.find_first_not_of(kSpace);
  if (begin == std::string::npos) return "";
  const std::size_t end = text.find_last_not_of(kSpace);
  return text.substr(begin, end - begin + 1);
}

// Locale-independent number parsing that must consume the whole token.
bool ParseDouble(const std::string& token, double* value) {
  const char* begin = token.data();
  const char* end = token.data() + token.size();
  if (begin != end && *begin == '+') ++begin;
  if (begin == end) return false;
  const std::from_chars_result result = std::from_chars(begin, end, *value);
  return result.ec == std::errc() && result.ptr == end;
}

bool ParseInt(const std::string& token, long long* value) {
  const char* begin = token.data();
  const char* end = token.data() + token.size();
  if (begin != end && *begin == '+') ++begin;
  if (begin == end) return false;
  const std::from_chars_result result = std::from_chars(begin, end, *value);
  return result.ec == std::errc() && result.ptr == end;
}

void CheckReadableFile(const std::string& path) {
  std::error_code error;
  const fs::file_status status = fs::status(path, error);
  if (!fs::exists(status)) Fail(path, "file not found");
  if (fs::is_directory(status)) Fail(path, "is a directory, expected a file");
}

// Lines without their '\n' (and without a trailing '\r', for CRLF files).
std::vector<std::string> SplitLines(const std::string& text) {
  std::vector<std::string> lines;
  std::size_t start = 0;
  while (start <= text.size()) {
    std::size_t end = text.find('\n', start);
    if (end == std::string::npos) end = text.size();
    std::string line = text.substr(start, end - start);
    if (!line.empty() && line.back() == '\r') line.pop_back();
    lines.push_back(std::move(line));
    start = end + 1;
  }
  // A final '\n' produces one empty "line" that is not in the file.
  if (!lines.empty() && lines.back().empty() && !text.empty() && text.back() == '\n') {
    lines.pop_back();
  }
  return lines;
}

void CreateParentFolder(const std::string& path) {
  const fs::path parent = fs::path(path).parent_path();
  if (parent.empty()) return;
  std::error_code error;
  fs::create_directories(parent, error);
  if (error) Fail(path, "cannot create folder " + parent.string() + ": " + error.message());
}

void WriteTextFile(const std::string& path, const std::string& content) {
  CreateParentFolder(path);
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  if (!out) Fail(path, "cannot open file for writing");
  out << content;
  out.close();
  if (!out) Fail(path, "write error");
}

// ---------------------------------------------------- camera_calibration YAML
//
// yaml-cpp parses the file; the reader below checks the layout
// camera_calibration writes: top-level `key: value` entries, each matrix a map
// of rows, cols and a data list. Messages give the line of the key at fault.

// One entry of a YAML map: its value and the (1-based) line of its key.
struct YamlEntry {
  YAML::Node value;
  int line = 0;
};
using YamlEntries = std::map<std::string, YamlEntry>;

// yaml-cpp counts lines from 0, messages from 1.
int LineOf(const YAML::Mark& mark) {
  return mark.line + 1;
}

// A scalar's text for messages; "{map}" or "[list]" for the other kinds.
std::string NodeText(const YAML::Node& node) {
  if (node.IsScalar()) return node.Scalar();
  if (node.IsMap()) return "{map}";
  if (node.IsSequence()) return "[list]";
  return "";
}

// yaml-cpp's parser messages, in this reader's words where it has them.
std::string ParserProblem(const std::string& message) {
  if (message == YAML::ErrorMsg::END_OF_SEQ_FLOW) return "unterminated '[' (missing closing bracket)";
  if (message == YAML::ErrorMsg::END_OF_MAP_FLOW) return "unterminated '{' (missing closing bracket)";
  if (message == YAML::ErrorMsg::FLOW_END) return "unbalanced brackets";
  if (message == YAML::ErrorMsg::TAB_IN_INDENTATION) return "tab in indentation (YAML allows spaces only)";
  if (message == YAML::ErrorMsg::MAP_VALUE) return "unexpected indentation or ':' (illegal map value)";
  return "invalid YAML: " + Printable(message, 80);
}

[[noreturn]] void FailAtMark(const std::string& path, const YAML::Mark& mark, const std::string& message) {
  if (mark.is_null()) Fail(path, message);
  FailAt(path, LineOf(mark), message);
}

// The document of `content`; a syntax error becomes one InputError line.
YAML::Node LoadYaml(const std::string& path, const std::string& content) {
  try {
    return YAML::Load(content);
  } catch (const YAML::Exception& error) {
    FailAtMark(path, error.mark, ParserProblem(error.msg));
  }
}

// The entries of a map node, whose keys must be distinct scalars.
YamlEntries MapEntries(const std::string& path, const YAML::Node& map) {
  YamlEntries entries;
  for (const auto& item : map) {
    const YAML::Node& key = item.first;
    const int line = LineOf(key.Mark());
    if (!key.IsScalar()) FailAt(path, line, "expected 'key: value', got the key " + Quote(NodeText(key)));
    if (!entries.emplace(key.Scalar(), YamlEntry{item.second, line}).second) {
      FailAt(path, line, "duplicate key " + Quote(key.Scalar()));
    }
  }
  return entries;
}

class CalibrationReader {
 public:
  CalibrationReader(const std::string& path, const YAML::Node& root) : path_(path) {
    if (!root.IsMap()) {
      FailAtMark(path_, root.Mark(), "expected 'key: value', got " + Quote(NodeText(root)));
    }
    entries_ = MapEntries(path_, root);
  }

  const YamlEntry* Find(const std::string& key) const {
    const auto it = entries_.find(key);
    return it == entries_.end() ? nullptr : &it->second;
  }

  const YamlEntry& Require(const std::string& key) const {
    const YamlEntry* entry = Find(key);
    if (entry == nullptr) Fail(path_, "missing key '" + key + "'");
    return *entry;
  }

  int PositiveInt(const YamlEntry& entry, const std::string& name) const {
    long long value = 0;
    if (!entry.value.IsScalar() || !ParseInt(entry.value.Scalar(), &value) || value <= 0 ||
        value > std::numeric_limits<int>::max()) {
      FailAt(path_, entry.line, name + " must be a positive integer, got " + Quote(NodeText(entry.value)));
    }
    return static_cast<int>(value);
  }

  std::string String(const std::string& key, const std::string& fallback) const {
    const YamlEntry* entry = Find(key);
    if (entry == nullptr) return fallback;
    if (entry->value.IsMap() || entry->value.IsSequence()) {
      FailAt(path_, entry->line, key + " must be a string");
    }
    return NodeText(entry->value);
  }

  // A `{rows, cols, data}` matrix; expected_cols < 0 accepts any column count.
  std::vector<double> Matrix(const YamlEntry& entry, const std::string& key, int expected_rows,
                             int expected_cols) const {
    if (!entry.value.IsMap()) FailAt(path_, entry.line, key + " must be a map with rows, cols and data");
    const YamlEntries children = MapEntries(path_, entry.value);
    const int rows = Dimension(children, entry.line, key, "rows");
    const int cols = Dimension(children, entry.line, key, "cols");
    if (rows != expected_rows) {
      FailAt(path_, Child(children, entry.line, key, "rows").line,
             key + ": rows is " + std::to_string(rows) + ", expected " + std::to_string(expected_rows));
    }
    if (expected_cols >= 0 && cols != expected_cols) {
      FailAt(path_, Child(children, entry.line, key, "cols").line,
             key + ": cols is " + std::to_string(cols) + ", expected " + std::to_string(expected_cols));
    }
    const YamlEntry& data = Child(children, entry.line, key, "data");
    if (!data.value.IsSequence()) FailAt(path_, data.line, key + ": data must be a list [a, b, ...]");
    if (static_cast<long long>(data.value.size()) != static_cast<long long>(rows) * cols) {
      FailAt(path_, data.line,
             key + ": data has " + std::to_string(data.value.size()) +
                 " values, expected rows*cols = " + std::to_string(static_cast<long long>(rows) * cols));
    }
    std::vector<double> values;
    values.reserve(data.value.size());
    for (const YAML::Node& item : data.value) {
      const std::string text = NodeText(item);
      double value = 0.0;
      if (!item.IsScalar() || !ParseDouble(text, &value)) {
        FailAt(path_, data.line, key + ": data value " + Quote(text) + " is not a number");
      }
      if (!std::isfinite(value)) {
        FailAt(path_, data.line, key + ": data value " + Quote(text) + " is not finite");
      }
      values.push_back(value);
    }
    return values;
  }

 private:
  // `line` is the matrix key's, for a missing entry.
  const YamlEntry& Child(const YamlEntries& children, int line, const std::string& key,
                         const std::string& name) const {
    const auto it = children.find(name);
    if (it == children.end()) FailAt(path_, line, key + ": missing key '" + name + "'");
    return it->second;
  }

  int Dimension(const YamlEntries& children, int line, const std::string& key,
                const std::string& name) const {
    const YamlEntry& child = Child(children, line, key, name);
    long long value = 0;
    if (!child.value.IsScalar() || !ParseInt(child.value.Scalar(), &value) || value < 0 || value > 1000000) {
      FailAt(path_, child.line,
             key + ": " + name + " must be a non-negative integer, got " + Quote(NodeText(child.value)));
    }
    return static_cast<int>(value);
  }

  std::string path_;
  YamlEntries entries_;
};

// A `{rows, cols, data}` matrix entry as camera_calibration writes it; the
// numbers in their shortest exact text, the data list in flow style.
void EmitMatrix(YAML::Emitter* out, const std::string& key, int rows, int cols,
                const std::vector<double>& data) {
  *out << YAML::Key << key << YAML::Value << YAML::BeginMap;
  *out << YAML::Key << "rows" << YAML::Value << rows;
  *out << YAML::Key << "cols" << YAML::Value << cols;
  *out << YAML::Key << "data" << YAML::Value << YAML::Flow << YAML::BeginSeq;
  for (const double value : data) *out << FormatDouble(value);
  *out << YAML::EndSeq << YAML::EndMap;
}

Eigen::Matrix<double, 3, 4> ProjectionOf(const PinholeCamera& camera) {
  Eigen::Matrix<double, 3, 4> projection = Eigen::Matrix<double, 3, 4>::Zero();
  projection(0, 0) = camera.fx;
  projection(0, 2) = camera.cx;
  projection(1, 1) = camera.fy;
  projection(1, 2) = camera.cy;
  projection(2, 2) = 1.0;
  return projection;
}

// ------------------------------------------------------------------- images

cv::Mat ReadImageFile(const std::string& path) {
  CheckReadableFile(path);
  std::error_code error;
  if (fs::file_size(path, error) == 0 && !error) Fail(path, "file is empty");
  cv::Mat image;
  try {
    image = cv::imread(path, cv::IMREAD_UNCHANGED);
  } catch (const cv::Exception& e) {
    Fail(path, "cannot be decoded (" + Trim(e.err) + ")");
  }
  if (image.empty()) Fail(path, "cannot be decoded (truncated, corrupt or unsupported format)");
  return image;
}

void WriteImageFile(const std::string& path, const cv::Mat& image, const std::vector<int>& params = {}) {
  CreateParentFolder(path);
  bool ok = false;
  try {
    ok = cv::imwrite(path, image, params);
  } catch (const cv::Exception& e) {
    Fail(path, "cannot write image (" + Trim(e.err) + ")");
  }
  if (!ok) Fail(path, "cannot write image");
}

std::string TypeText(const cv::Mat& image) {
  const int depth = image.depth();
  const char* names[] = {"8U", "8S", "16U", "16S", "32S", "32F", "64F", "16F"};
  const std::string name = depth >= 0 && depth < 8 ? names[depth] : "?";
  return name + "C" + std::to_string(image.channels());
}

bool HasExtension(const std::string& path, std::initializer_list<const char*> extensions) {
  std::string extension = fs::path(path).extension().string();
  std::transform(extension.begin(), extension.end(), extension.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  for (const char* candidate : extensions) {
    if (extension == candidate) return true;
  }
  return false;
}

}  // namespace

// ------------------------------------------------------------- calibration

CameraCalibration CameraCalibration::FromCamera(const PinholeCamera& camera, const std::string& name) {
  CameraCalibration calibration;
  calibration.camera = camera;
  calibration.camera_name = name;
  calibration.projection = ProjectionOf(camera);
  return calibration;
}

bool CameraCalibration::HasDistortion() const {
  return std::any_of(distortion.begin(), distortion.end(), [](double d) { return d != 0.0; });
}

namespace {

// The intrinsics of camera_matrix, which must be [fx 0 cx; 0 fy cy; 0 0 1].
void ReadCameraMatrix(const std::string& path, const CalibrationReader& reader, PinholeCamera* camera) {
  const YamlEntry& k_entry = reader.Require("camera_matrix");
  const std::vector<double> k = reader.Matrix(k_entry, "camera_matrix", 3, 3);
  // A pinhole camera without skew; a tiny tolerance for hand-edited files.
  const double tolerance = 1e-9 * std::max({1.0, std::abs(k[0]), std::abs(k[4])});
  if (std::abs(k[1]) > tolerance || std::abs(k[3]) > tolerance || std::abs(k[6]) > tolerance ||
      std::abs(k[7]) > tolerance || std::abs(k[8] - 1.0) > tolerance) {
    std::string text;
    for (int i = 0; i < 9; ++i) text += (i ? (i % 3 ? " " : "; ") : "") + FormatDouble(k[i]);
    FailAt(path, k_entry.line, "camera_matrix must be [fx 0 cx; 0 fy cy; 0 0 1], got [" + text + "]");
  }
  camera->fx = k[0];
  camera->cx = k[2];
  camera->fy = k[4];
  camera->cy = k[5];
  if (camera->fx <= 0.0 || camera->fy <= 0.0) {
    FailAt(path, k_entry.line,
           "camera_matrix: focal length (fx, fy) = (" + FormatDouble(camera->fx) + ", " +
               FormatDouble(camera->fy) + ") must be positive");
  }
}

CameraCalibration ReadCalibration(const std::string& path, const YAML::Node& root) {
  const CalibrationReader reader(path, root);
  CameraCalibration calibration;
  PinholeCamera& camera = calibration.camera;
  camera.width = reader.PositiveInt(reader.Require("image_width"), "image_width");
  camera.height = reader.PositiveInt(reader.Require("image_height"), "image_height");
  calibration.camera_name = reader.String("camera_name", calibration.camera_name);
  ReadCameraMatrix(path, reader, &camera);

  calibration.distortion_model = reader.String("distortion_model", calibration.distortion_model);
  if (const YamlEntry* entry = reader.Find("distortion_coefficients")) {
    calibration.distortion = reader.Matrix(*entry, "distortion_coefficients", 1, -1);
  }
  if (const YamlEntry* entry = reader.Find("rectification_matrix")) {
    const std::vector<double> r = reader.Matrix(*entry, "rectification_matrix", 3, 3);
    calibration.rectification = Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(r.data());
  }
  // Missing P defaults to [K | 0], what the writer would have written.
  calibration.projection = ProjectionOf(camera);
  if (const YamlEntry* entry = reader.Find("projection_matrix")) {
    const std::vector<double> p = reader.Matrix(*entry, "projection_matrix", 3, 4);
    calibration.projection = Eigen::Map<const Eigen::Matrix<double, 3, 4, Eigen::RowMajor>>(p.data());
  }
  return calibration;
}

}  // namespace

CameraCalibration ReadCameraYaml(const std::string& path) {
  const YAML::Node root = LoadYaml(path, ReadTextFile(path));
  if (root.IsNull()) Fail(path, "file is empty (expected camera_calibration YAML)");
  try {
    return ReadCalibration(path, root);
  } catch (const YAML::Exception& error) {  // not expected: the reader only walks the nodes
    FailAtMark(path, error.mark, "invalid YAML: " + Printable(error.msg, 80));
  }
}

void WriteCameraYaml(const std::string& path, const CameraCalibration& calibration) {
  const PinholeCamera& camera = calibration.camera;
  const std::vector<double> k = {camera.fx, 0.0, camera.cx, 0.0, camera.fy, camera.cy, 0.0, 0.0, 1.0};
  std::vector<double> r(9);
  std::vector<double> p(12);
  const Eigen::Matrix<double, 3, 4> projection =
      calibration.projection.isZero(0.0) ? ProjectionOf(camera) : calibration.projection;
  for (int row = 0; row < 3; ++row) {
    for (int col = 0; col < 3; ++col) r[row * 3 + col] = calibration.rectification(row, col);
    for (int col = 0; col < 4; ++col) p[row * 4 + col] = projection(row, col);
  }
  YAML::Emitter out;
  out << YAML::BeginMap;
  out << YAML::Key << "image_width" << YAML::Value << camera.width;
  out << YAML::Key << "image_height" << YAML::Value << camera.height;
  out << YAML::Key << "camera_name" << YAML::Value << calibration.camera_name;
  EmitMatrix(&out, "camera_matrix", 3, 3, k);
  out << YAML::Key << "distortion_model" << YAML::Value << calibration.distortion_model;
  EmitMatrix(&out, "distortion_coefficients", 1, static_cast<int>(calibration.distortion.size()),
             calibration.distortion);
  EmitMatrix(&out, "rectification_matrix", 3, 3, r);
  EmitMatrix(&out, "projection_matrix", 3, 4, p);
  out << YAML::EndMap;
  if (!out.good()) Fail(path, "cannot write the calibration as YAML: " + out.GetLastError());
  WriteTextFile(path, std::string(out.c_str()) + "\n");
}

// ---------------------------------------------------------------- frames.csv

// ------------------------------------------------------------- sensor.yaml

double ReadSensorYaml(const std::string& path, const std::vector<FrameRecord>& frames) {
  const YAML::Node root = LoadYaml(path, ReadTextFile(path));
  if (root.IsNull()) Fail(path, "file is empty (expected 'readout_time: <seconds>')");
  if (!root.IsMap())
    FailAtMark(path, root.Mark(), "expected 'readout_time: <seconds>', got " + Quote(NodeText(root)));
  const YamlEntries entries = MapEntries(path, root);
  for (const auto& [key, entry] : entries) {
    if (key != "readout_time")
      FailAt(path, entry.line, "unknown key " + Quote(key) + " (expected readout_time)");
  }
  const auto it = entries.find("readout_time");
  if (it == entries.end()) Fail(path, "missing key 'readout_time'");
  const YamlEntry& entry = it->second;
  double readout = 0.0;
  if (!entry.value.IsScalar() || !ParseDouble(Trim(entry.value.Scalar()), &readout)) {
    FailAt(path, entry.line, "readout_time must be a number of seconds, got " + Quote(NodeText(entry.value)));
  }
  const std::string problem = ReadoutTimeProblem(readout, frames);
  if (!problem.empty()) FailAt(path, entry.line, problem);
  return readout;
}

std::string ReadoutTimeProblem(double readout_time, const std::vector<FrameRecord>& frames) {
  if (!std::isfinite(readout_time) || readout_time < 0.0) {
    return "readout_time must be finite and >= 0, got " + MessageNumber(readout_time);
  }
  // A row cannot start reading out after the next frame's row 0: at most one
  // frame interval (with a relative tolerance for stamps rounded in the CSV).
  for (std::size_t i = 1; i < frames.size(); ++i) {
    const double interval = frames[i].stamp - frames[i - 1].stamp;
    if (readout_time > interval * (1.0 + 1e-9)) {
      return "readout_time " + MessageNumber(readout_time) + " s exceeds the frame interval " +
             MessageNumber(interval) + " s between frames " + std::to_string(i - 1) + " and " +
             std::to_string(i);
    }
  }
  return "";
}

void WriteSensorYaml(const std::string& path, double readout_time) {
  if (!std::isfinite(readout_time) || readout_time < 0.0) {
    Fail(path, "cannot write readout_time " + MessageNumber(readout_time) + " (must be finite and >= 0)");
  }
  YAML::Emitter out;
  out.SetDoublePrecision(17);
  out << YAML::BeginMap << YAML::Key << "readout_time" << YAML::Value << readout_time << YAML::EndMap;
  WriteTextFile(path, std::string(out.c_str()) + "\n");
}

std::vector<FrameRecord> ReadFramesCsv(const std::string& path) {
  static const char* kHeader = "index,stamp,exposure";
  const std::string content = ReadTextFile(path);
  std::vector<std::string> lines = SplitLines(content);
  // Spreadsheet programs may prefix a UTF-8 byte order mark.
  if (!lines.empty() && lines[0].rfind("\xEF\xBB\xBF", 0) == 0) lines[0].erase(0, 3);
  for (std::string& line : lines) line = Trim(line);
  // Trailing empty lines are tolerated; empty lines elsewhere are not.
  while (!lines.empty() && lines.back().empty()) lines.pop_back();
  if (lines.empty()) Fail(path, std::string("file is empty (expected header '") + kHeader + "')");
  if (lines[0] != kHeader) {
    FailAt(path, 1, std::string("header must be '") + kHeader + "', got " + Quote(lines[0]));
  }
  if (lines.size() == 1) Fail(path, "no frames after the header");

  std::vector<FrameRecord> frames;
  std::vector<std::string> stamp_texts;
  frames.reserve(lines.size() - 1);
  for (std::size_t i = 1; i < lines.size(); ++i) {
    const int number = static_cast<int>(i) + 1;
    const std::string& line = lines[i];
    if (line.empty()) FailAt(path, number, "empty line");
    std::vector<std::string> fields;
    std::stringstream stream(line);
    std::string field;
    while (std::getline(stream, field, ',')) fields.push_back(Trim(field));
    if (line.back() == ',') fields.push_back("");
    if (fields.size() != 3) {
      FailAt(path, number,
             "expected 3 fields 'index,stamp,exposure', got " + std::to_string(fields.size()) + " in " +
                 Quote(line));
    }
    FrameRecord frame;
    long long index = 0;
    if (!ParseInt(fields[0], &index))
      FailAt(path, number, "index " + Quote(fields[0]) + " is not an integer");
    const long long expected = static_cast<long long>(frames.size());
    if (index != expected) {
      FailAt(path, number,
             "index " + fields[0] + " should be " + std::to_string(expected) +
                 " (indices are contiguous from 0)");
    }
    frame.index = static_cast<int>(index);
    if (!ParseDouble(fields[1], &frame.stamp))
      FailAt(path, number, "stamp " + Quote(fields[1]) + " is not a number");
    if (!std::isfinite(frame.stamp)) FailAt(path, number, "stamp " + fields[1] + " is not finite");
    if (!ParseDouble(fields[2], &frame.exposure)) {
      FailAt(path, number, "exposure " + Quote(fields[2]) + " is not a number");
    }
    if (!std::isfinite(frame.exposure) || frame.exposure <= 0.0) {
      FailAt(path, number, "exposure " + fields[2] + " must be finite and > 0");
    }
    if (!frames.empty() && !(frame.stamp > frames.back().stamp)) {
      FailAt(path, number, "stamp " + fields[1] + " is not after the previous stamp " + stamp_texts.back());
    }
    frames.push_back(frame);
    stamp_texts.push_back(fields[1]);
  }

  // The exposure [t_c - exposure, t_c] must fit in the frame interval. The
  // tolerance covers rounding of decimal stamps (e.g. 0.3 - 0.2 < 0.1) and
  // large epoch stamps.
  for (std::size_t i = 0; i < frames.size() && frames.size() > 1; ++i) {
    const bool first = i == 0;
    const double a = first ? frames[0].stamp : frames[i - 1].stamp;
    const double b = first ? frames[1].stamp : frames[i].stamp;
    const double interval = b - a;
    const double tolerance =
        1e-12 + 8.0 * std::numeric_limits<double>::epsilon() * std::max(std::abs(a), std::abs(b));
    if (frames[i].exposure > interval + tolerance) {
      FailAt(path, static_cast<int>(i) + 2,
             "exposure " + MessageNumber(frames[i].exposure) + " s exceeds the frame interval " +
                 MessageNumber(interval) + " s (gap to the " + (first ? "next" : "previous") + " stamp)");
    }
  }
  return frames;
}

void WriteFramesCsv(const std::string& path, const std::vector<FrameRecord>& frames) {
  std::string out = "index,stamp,exposure\n";
  for (const FrameRecord& frame : frames) {
    out += std::to_string(frame.index) + "," + FormatDouble(frame.stamp) + "," +
           FormatDouble(frame.exposure) + "\n";
  }
  WriteTextFile(path, out);
}

// -------------------------------------------------------------- TUM poses

std::vector<StampedPose> ReadTumTrajectory(const std::string& path) {
  const std::string content = ReadTextFile(path);
  const std::vector<std::string> lines = SplitLines(content);
  std::vector<StampedPose> poses;
  std::vector<std::string> fields;
  for (std::size_t i = 0; i < lines.size(); ++i) {
    const int number = static_cast<int>(i) + 1;
    const std::string line = Trim(lines[i]);
    if (line.empty() || line[0] == '#') continue;
    fields.clear();
    std::istringstream stream(line);
    std::string field;
    while (stream >> field) fields.push_back(field);
    if (fields.size() != 8) {
      FailAt(path, number,
             "expected 8 values 'stamp tx ty tz qx qy qz qw', got " + std::to_string(fields.size()));
    }
    double v[8];
    for (int j = 0; j < 8; ++j) {
      if (!ParseDouble(fields[j], &v[j]))
        FailAt(path, number, "value " + Quote(fields[j]) + " is not a number");
      if (!std::isfinite(v[j])) FailAt(path, number, "value " + fields[j] + " is not finite");
    }
    const Eigen::Quaterniond q(v[7], v[4], v[5], v[6]);  // (w, x, y, z)
    if (q.norm() < 1e-6) {
      FailAt(path, number,
             "quaternion (qx qy qz qw) = (" + fields[4] + " " + fields[5] + " " + fields[6] + " " +
                 fields[7] + ") has (near) zero norm");
    }
    StampedPose pose;
    pose.stamp = v[0];
    pose.T_world_cam = SE3(q.normalized(), Eigen::Vector3d(v[1], v[2], v[3]));
    poses.push_back(pose);
  }
  if (poses.empty()) Fail(path, "no poses (expected lines 'stamp tx ty tz qx qy qz qw')");
  return poses;
}

void WriteTumTrajectory(const std::string& path, const std::vector<StampedPose>& poses) {
  std::string out = "# stamp tx ty tz qx qy qz qw (T_world_cam, camera -> world)\n";
  for (const StampedPose& pose : poses) {
    Eigen::Quaterniond q = pose.T_world_cam.quaternion();
    if (q.w() < 0.0) q.coeffs() = -q.coeffs();  // canonical sign, same rotation
    const Eigen::Vector3d& t = pose.T_world_cam.translation();
    const double values[8] = {pose.stamp, t.x(), t.y(), t.z(), q.x(), q.y(), q.z(), q.w()};
    for (int j = 0; j < 8; ++j) out += (j ? " " : "") + FormatDouble(values[j]);
    out += "\n";
  }
  WriteTextFile(path, out);
}

// ------------------------------------------------------------------ images

cv::Mat ReadDepthTiff(const std::string& path) {
  const cv::Mat depth = ReadImageFile(path);
  if (depth.type() != CV_32FC1) {
    Fail(path, "depth must be float32 single-channel (32FC1), got " + TypeText(depth));
  }
  return depth;
}

void WriteDepthTiff(const std::string& path, const cv::Mat& depth) {
  if (depth.empty()) Fail(path, "cannot write an empty depth map");
  if (depth.type() != CV_32FC1) Fail(path, "depth to write must be 32FC1, got " + TypeText(depth));
  if (!HasExtension(path, {".tif", ".tiff"})) Fail(path, "depth file name must end with .tiff or .tif");
  WriteImageFile(path, depth);
}

// 4-channel (alpha) images are rejected rather than silently flattened:
// the sequence format holds gray or colour frames only.
cv::Mat ReadImage8(const std::string& path) {
  const cv::Mat image = ReadImageFile(path);
  if (image.depth() != CV_8U) Fail(path, "image must be 8-bit, got " + TypeText(image));
  if (image.channels() != 1 && image.channels() != 3) {
    Fail(path, "image must be gray or colour (1 or 3 channels), got " + std::to_string(image.channels()) +
                   " channels");
  }
  return image;
}

void WriteImage(const std::string& path, const cv::Mat& image) {
  if (image.empty()) Fail(path, "cannot write an empty image");
  const int depth = image.depth();
  const int channels = image.channels();
  if ((depth != CV_8U && depth != CV_16U) || (channels != 1 && channels != 3 && channels != 4)) {
    Fail(path, "image to write must be 8- or 16-bit with 1, 3 or 4 channels, got " + TypeText(image));
  }
  WriteImageFile(path, image);
}

std::string FrameStem(int index) {
  char buffer[32];
  std::snprintf(buffer, sizeof(buffer), "%06d", index);
  return buffer;
}

// --------------------------------------------------------- whole sequences

Sequence ReadSequence(const std::string& folder, bool read_ground_truth) {
  const fs::path root(folder);
  std::error_code error;
  if (!fs::is_directory(root, error)) Fail(folder, "sequence folder not found");
  const std::string camera_path = (root / "camera.yaml").string();

  Sequence sequence;
  sequence.calibration = ReadCameraYaml(camera_path);
  sequence.frames = ReadFramesCsv((root / "frames.csv").string());
  const fs::path sensor_path = root / "sensor.yaml";
  if (fs::exists(sensor_path, error))
    sequence.readout_time = ReadSensorYaml(sensor_path.string(), sequence.frames);
  const PinholeCamera& camera = sequence.calibration.camera;
  sequence.images.reserve(sequence.frames.size());
  for (const FrameRecord& frame : sequence.frames) {
    const std::string path = (root / "images" / (FrameStem(frame.index) + ".png")).string();
    cv::Mat image = ReadImage8(path);
    if (image.cols != camera.width || image.rows != camera.height) {
      Fail(path, "image is " + SizeText(image.cols, image.rows) + " but " + camera_path + " says " +
                     SizeText(camera.width, camera.height));
    }
    if (!sequence.images.empty() && image.channels() != sequence.images.front().channels()) {
      Fail(path, "image has " + std::to_string(image.channels()) + " channel(s) but frame 0 has " +
                     std::to_string(sequence.images.front().channels()));
    }
    sequence.images.push_back(std::move(image));
  }

  const fs::path gt_root = root / "gt";
  if (!read_ground_truth || !fs::exists(gt_root, error)) return sequence;
  if (!fs::is_directory(gt_root, error)) Fail(gt_root.string(), "is not a folder");

  SequenceGroundTruth gt;
  const std::string gt_camera_path = (gt_root / "camera.yaml").string();
  gt.calibration = ReadCameraYaml(gt_camera_path);
  const PinholeCamera& gt_camera = gt.calibration.camera;
  auto check_size = [&](const std::string& path, const cv::Mat& image) {
    if (image.cols != gt_camera.width || image.rows != gt_camera.height) {
      Fail(path, "image is " + SizeText(image.cols, image.rows) + " but " + gt_camera_path + " says " +
                     SizeText(gt_camera.width, gt_camera.height));
    }
  };
  gt.latent.reserve(sequence.frames.size());
  gt.depth.reserve(sequence.frames.size());
  for (const FrameRecord& frame : sequence.frames) {
    const std::string stem = FrameStem(frame.index);
    const std::string latent_path = (gt_root / "latent" / (stem + ".png")).string();
    cv::Mat latent = ReadImage8(latent_path);
    check_size(latent_path, latent);
    if (!gt.latent.empty() && latent.channels() != gt.latent.front().channels()) {
      Fail(latent_path, "image has " + std::to_string(latent.channels()) +
                            " channel(s) but the first latent image has " +
                            std::to_string(gt.latent.front().channels()));
    }
    gt.latent.push_back(std::move(latent));
    const std::string depth_path = (gt_root / "depth" / (stem + ".tiff")).string();
    cv::Mat depth = ReadDepthTiff(depth_path);
    check_size(depth_path, depth);
    gt.depth.push_back(std::move(depth));
  }
  const std::string poses_path = (gt_root / "poses.txt").string();
  gt.poses = ReadTumTrajectory(poses_path);
  if (gt.poses.size() != sequence.frames.size()) {
    Fail(poses_path, std::to_string(gt.poses.size()) + " poses for " +
                         std::to_string(sequence.frames.size()) + " frames (one pose per frame)");
  }
  constexpr double kStampTolerance = 1e-6;  // s
  for (std::size_t i = 0; i < gt.poses.size(); ++i) {
    if (!(std::abs(gt.poses[i].stamp - sequence.frames[i].stamp) <= kStampTolerance)) {
      Fail(poses_path, "pose " + std::to_string(i) + " has stamp " + FormatDouble(gt.poses[i].stamp) +
                           " but frame " + std::to_string(i) + " has stamp " +
                           FormatDouble(sequence.frames[i].stamp) + " (tolerance 1e-6 s)");
    }
  }
  sequence.ground_truth = std::move(gt);
  return sequence;
}

void WriteSequence(const std::string& folder, const Sequence& sequence) {
  const fs::path root(folder);
  const std::size_t count = sequence.frames.size();
  if (sequence.images.size() != count) {
    Fail(folder, "cannot write " + std::to_string(sequence.images.size()) + " images for " +
                     std::to_string(count) + " frames");
  }
  if (sequence.ground_truth) {
    const SequenceGroundTruth& gt = *sequence.ground_truth;
    if (gt.latent.size() != count || gt.depth.size() != count || gt.poses.size() != count) {
      Fail(folder, "ground truth needs one latent image, depth map and pose per frame, got " +
                       std::to_string(gt.latent.size()) + ", " + std::to_string(gt.depth.size()) + ", " +
                       std::to_string(gt.poses.size()) + " for " + std::to_string(count) + " frames");
    }
  }
  std::error_code error;
  fs::create_directories(root / "images", error);
  if (error) Fail(folder, "cannot create folder: " + error.message());

  WriteCameraYaml((root / "camera.yaml").string(), sequence.calibration);
  WriteFramesCsv((root / "frames.csv").string(), sequence.frames);
  const fs::path sensor_path = root / "sensor.yaml";
  if (sequence.readout_time > 0.0) {
    WriteSensorYaml(sensor_path.string(), sequence.readout_time);
  } else if (fs::exists(sensor_path, error)) {
    fs::remove(sensor_path, error);  // a global-shutter sequence has none
    if (error) Fail(sensor_path.string(), "cannot remove the stale file: " + error.message());
  }
  for (std::size_t i = 0; i < count; ++i) {
    const std::string stem = FrameStem(sequence.frames[i].index);
    WriteImage((root / "images" / (stem + ".png")).string(), sequence.images[i]);
  }
  if (!sequence.ground_truth) return;

  const SequenceGroundTruth& gt = *sequence.ground_truth;
  const fs::path gt_root = root / "gt";
  WriteCameraYaml((gt_root / "camera.yaml").string(), gt.calibration);
  for (std::size_t i = 0; i < count; ++i) {
    const std::string stem = FrameStem(sequence.frames[i].index);
    WriteImage((gt_root / "latent" / (stem + ".png")).string(), gt.latent[i]);
    WriteDepthTiff((gt_root / "depth" / (stem + ".tiff")).string(), gt.depth[i]);
  }
  WriteTumTrajectory((gt_root / "poses.txt").string(), gt.poses);
}

std::string ReadTextFile(const std::string& path) {
  CheckReadableFile(path);
  std::ifstream in(path, std::ios::binary);
  if (!in) Fail(path, "cannot open file for reading");
  std::ostringstream content;
  content << in.rdbuf();
  if (in.bad()) Fail(path, "read error");
  return content.str();
}

}  // namespace deblur_sr_mvs
