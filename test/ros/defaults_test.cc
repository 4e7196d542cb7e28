// One source of the node's defaults: NodeParameters' initialisers, with the
// names of ForEachParameter. config/default.yaml, cfg/Estimator.cfg (through
// the generated EstimatorConfig) and the parameter table of the README must
// agree with them, and they are the core's EstimatorOptions / StreamOptions
// defaults but for the node's time cap of one window and its refinement of
// the published depth. The hand-written
// reconfigure mapping is checked parameter by parameter. No ROS master needed.
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <regex>
#include <sstream>
#include <string>
#include <vector>

#include <dynamic_reconfigure/Config.h>
#include <gtest/gtest.h>
#include <yaml-cpp/yaml.h>
#include <boost/any.hpp>

#include "deblur_sr_mvs/ros/node_parameters.h"

namespace deblur_sr_mvs {
namespace ros_glue {
namespace {

// A default value: numbers compare as numbers (30 == 30.0), the rest as text.
struct Value {
  std::string text;
  bool numeric = false;
  double number = 0.0;
};

Value Number(double number) {
  std::ostringstream text;
  text << number;
  return Value{text.str(), true, number};
}
Value Text(const std::string& text) {
  return Value{text, false, 0.0};
}
Value Flag(bool flag) {
  return Text(flag ? "true" : "false");
}

// ForEachParameter's visitor that records every value, spelt as in the YAML.
class DefaultsWriter {
 public:
  explicit DefaultsWriter(std::map<std::string, Value>* values) : values_(values) {}
  void operator()(const char* name, double value) const { (*values_)[name] = Number(value); }
  void operator()(const char* name, int value) const { (*values_)[name] = Number(value); }
  void operator()(const char* name, bool value) const { (*values_)[name] = Flag(value); }
  void operator()(const char* name, const std::string& value) const { (*values_)[name] = Text(value); }
  void operator()(const char* name, StampPosition value) const { (*values_)[name] = Text(ToString(value)); }
  void operator()(const char* name, EstimatorMode value) const { (*values_)[name] = Text(ToString(value)); }
  void operator()(const char* name, const SecondsOrAuto& value) const {
    (*values_)[name] = value.automatic ? Text("auto") : Number(value.seconds);
  }
  void operator()(const char* name, DistortionPolicy value) const {
    (*values_)[name] = Flag(value == DistortionPolicy::kAssumeRectified);  // ~assume_rectified
  }

 private:
  std::map<std::string, Value>* values_;
};

std::map<std::string, Value> ValuesOf(const NodeParameters& params) {
  std::map<std::string, Value> values;
  ForEachParameter(params, DefaultsWriter(&values));
  return values;
}

const std::map<std::string, Value>& NodeDefaults() {
  static const std::map<std::string, Value> defaults = ValuesOf(NodeParameters());
  return defaults;
}

std::string Trim(const std::string& text) {
  const size_t first = text.find_first_not_of(" \t");
  if (first == std::string::npos) return "";
  return text.substr(first, text.find_last_not_of(" \t") - first + 1);
}

// Documentation spelling -> value: `code` and "quotes" are dropped.
std::string Unquote(std::string text) {
  text = Trim(text);
  if (text.size() >= 2 && text.front() == '`' && text.back() == '`')
    text = Trim(text.substr(1, text.size() - 2));
  if (text.size() >= 2 && text.front() == '"' && text.back() == '"') text = text.substr(1, text.size() - 2);
  return text;
}

// "" when `written` (from a file) is `expected`; else what differs.
std::string Mismatch(const std::string& name, const std::string& written, const Value& expected) {
  bool same = false;
  if (expected.numeric) {
    char* end = nullptr;
    const double number = std::strtod(written.c_str(), &end);
    same = !written.empty() && *end == '\0' && number == expected.number;
  } else {
    same = written == expected.text;
  }
  if (same) return "";
  return "  " + name + ": '" + written + "', the node's default is '" + expected.text + "'\n";
}

TEST(NodeDefaults, AreTheCoresDefaultsButTheTimeCap) {
  NodeParameters core;
  core.estimator = EstimatorOptions();
  core.stream = StreamOptions();
  const std::map<std::string, Value> core_values = ValuesOf(core);
  for (const auto& [name, value] : NodeDefaults()) {
    // The node's own: its time cap of one window, and the published depth
    // refined as estimate_sequence refines its output (NodeEstimatorOptions).
    if (name == "max_window_seconds" || name == "depth_sweep" || name == "depth_consistency_radius") continue;
    const Value& from_core = core_values.at(name);
    EXPECT_TRUE(from_core.numeric == value.numeric &&
                (value.numeric ? from_core.number == value.number : from_core.text == value.text))
        << name << ": the node's default is " << value.text << ", the core's " << from_core.text;
  }
  // A live node caps each window; the core's estimator does not.
  EXPECT_GT(NodeParameters().estimator.max_seconds, 0.0);
  EXPECT_EQ(EstimatorOptions().max_seconds, 0.0);
  EXPECT_TRUE(NodeParameters().estimator.depth_sweep.on_output);
  EXPECT_FALSE(EstimatorOptions().depth_sweep.on_output);
  EXPECT_EQ(NodeParameters().estimator.depth_consistency.radius, 2);
  EXPECT_EQ(EstimatorOptions().depth_consistency.radius, 0);
  // Every default is valid, but the exposure time the user must give.
  NodeParameters params;
  EXPECT_THROW(params.Check(), InputError);
  params.exposure_time = 0.02;
  EXPECT_NO_THROW(params.Check());
}

TEST(NodeDefaults, DefaultYamlHasEveryParameterWithTheNodesDefault) {
  const std::string path = DSM_SOURCE_DIR "/config/default.yaml";
  const YAML::Node yaml = YAML::LoadFile(path);
  ASSERT_TRUE(yaml.IsMap()) << path;
  std::string problems;
  for (const auto& entry : yaml) {
    const std::string name = entry.first.as<std::string>();
    const auto expected = NodeDefaults().find(name);
    if (expected == NodeDefaults().end()) {
      problems += "  " + name + ": not a parameter of the node\n";
    } else if (!entry.second.IsScalar()) {
      problems += "  " + name + ": not a single value\n";
    } else {
      problems += Mismatch(name, entry.second.Scalar(), expected->second);
    }
  }
  for (const auto& entry : NodeDefaults()) {
    if (!yaml[entry.first]) problems += "  " + entry.first + ": missing\n";
  }
  EXPECT_TRUE(problems.empty()) << path << " disagrees with NodeParameters:\n" << problems;
}

std::string CfgValueText(const EstimatorConfig::AbstractParamDescriptionConstPtr& description) {
  boost::any value;
  description->getValue(EstimatorConfig::__getDefault__(), value);
  std::ostringstream text;
  if (description->type == "int") {
    text << boost::any_cast<int>(value);
  } else if (description->type == "double") {
    text.precision(17);
    text << boost::any_cast<double>(value);
  } else if (description->type == "bool") {
    text << (boost::any_cast<bool>(value) ? "true" : "false");
  } else {
    text << boost::any_cast<std::string>(value);
  }
  return text.str();
}

TEST(NodeDefaults, ReconfigureDefaultsAreTheNodes) {
  std::string problems;
  const auto& descriptions = EstimatorConfig::__getParamDescriptions__();
  ASSERT_FALSE(descriptions.empty());
  for (const auto& description : descriptions) {
    const auto expected = NodeDefaults().find(description->name);
    if (expected == NodeDefaults().end()) {
      problems += "  " + description->name + ": not a parameter of the node\n";
      continue;
    }
    problems += Mismatch(description->name, CfgValueText(description), expected->second);
  }
  // What the node answers the server with at start: its own values.
  NodeParameters params;
  params.exposure_time = 0.02;
  const EstimatorConfig config = ConfigOf(params);
  for (const auto& description : descriptions) {
    boost::any from_node, from_cfg;
    description->getValue(config, from_node);
    description->getValue(EstimatorConfig::__getDefault__(), from_cfg);
    if (description->type == "int" && boost::any_cast<int>(from_node) != boost::any_cast<int>(from_cfg)) {
      problems += "  " + description->name + ": ConfigOf(NodeParameters()) differs from the cfg default\n";
    }
    if (description->type == "double" &&
        boost::any_cast<double>(from_node) != boost::any_cast<double>(from_cfg)) {
      problems += "  " + description->name + ": ConfigOf(NodeParameters()) differs from the cfg default\n";
    }
  }
  EXPECT_TRUE(problems.empty()) << "cfg/Estimator.cfg disagrees with NodeParameters:\n" << problems;
}

// WithConfig and ConfigOf map each cfg parameter by hand: every one must reach
// the node parameter of the same name and come back.
TEST(NodeDefaults, ReconfigureMapsEveryParameterToItsNamesake) {
  NodeParameters params;
  params.exposure_time = 0.02;
  std::string problems;
  for (const auto& description : EstimatorConfig::__getParamDescriptions__()) {
    EstimatorConfig config = ConfigOf(params);
    // A different valid value, set through the generated description: one
    // more, or half of a real number.
    double changed = 0.0;
    boost::any value;
    description->getValue(config, value);
    dynamic_reconfigure::Config message;
    if (description->type == "int") {
      changed = boost::any_cast<int>(value) + 1;
      dynamic_reconfigure::IntParameter parameter;
      parameter.name = description->name;
      parameter.value = static_cast<int>(changed);
      message.ints.push_back(parameter);
    } else if (description->type == "double") {
      changed = boost::any_cast<double>(value) * 0.5;
      dynamic_reconfigure::DoubleParameter parameter;
      parameter.name = description->name;
      parameter.value = changed;
      message.doubles.push_back(parameter);
    } else {
      problems +=
          "  " + description->name + ": a " + description->type + " (the test knows int and double)\n";
      continue;
    }
    ASSERT_TRUE(description->fromMessage(message, config)) << description->name;
    NodeParameters updated;
    try {
      updated = WithConfig(params, config);
    } catch (const InputError& error) {
      problems += "  " + description->name + ": " + error.what() + "\n";
      continue;
    }
    const std::map<std::string, Value> values = ValuesOf(updated);
    const Value& reached = values.at(description->name);
    if (!reached.numeric || reached.number != changed) {
      problems += "  " + description->name + " = " + std::to_string(changed) + " reached the node as " +
                  reached.text + "\n";
    }
    boost::any back;
    description->getValue(ConfigOf(updated), back);
    const double back_number =
        description->type == "int" ? boost::any_cast<int>(back) : boost::any_cast<double>(back);
    if (back_number != changed) problems += "  " + description->name + ": ConfigOf does not give it back\n";
  }
  EXPECT_TRUE(problems.empty()) << "WithConfig / ConfigOf:\n" << problems;
}

// The parameter table of a Markdown file: the rows after a header row whose
// first cell is "Parameter" and second "Default". A row names its parameters
// in `code` in the first cell ("(dyn)" and the like are ignored); a default
// cell with as many comma-separated values as names gives one to each.
// Returns false when the file has no such table.
bool ReadParameterTable(const std::string& path, std::map<std::string, std::string>* defaults,
                        std::string* problems) {
  std::ifstream file(path);
  std::string line;
  bool in_table = false;
  const std::regex code_name("`([A-Za-z0-9_]+)`");
  while (std::getline(file, line)) {
    line = Trim(line);
    std::vector<std::string> cells;
    if (!line.empty() && line.front() == '|') {
      std::stringstream row(line.substr(1));
      std::string cell;
      while (std::getline(row, cell, '|')) cells.push_back(Trim(cell));
    }
    if (!in_table) {
      in_table =
          cells.size() >= 2 && cells[0] == "Parameter" && cells[1].find("Default") != std::string::npos;
      continue;
    }
    if (cells.size() < 2) break;                                           // the end of the table
    if (cells[0].find_first_not_of("-: ") == std::string::npos) continue;  // |---|---|
    std::vector<std::string> names;
    for (std::sregex_iterator it(cells[0].begin(), cells[0].end(), code_name), end; it != end; ++it) {
      names.push_back((*it)[1]);
    }
    if (names.empty()) names.push_back(Unquote(cells[0]));
    std::vector<std::string> values{cells[1]};
    if (names.size() > 1) {
      values.clear();
      std::stringstream list(cells[1]);
      std::string value;
      while (std::getline(list, value, ',')) values.push_back(value);
    }
    if (values.size() != names.size()) {
      *problems += "  row '" + line + "': " + std::to_string(names.size()) + " names but " +
                   std::to_string(values.size()) + " defaults\n";
      continue;
    }
    for (size_t i = 0; i < names.size(); ++i) (*defaults)[names[i]] = Unquote(values[i]);
  }
  return in_table;
}

TEST(NodeDefaults, ReadmeTableHasEveryParameterWithTheNodesDefault) {
  // The README's table, or a docs/ page's if the README has none.
  std::vector<std::string> candidates{DSM_SOURCE_DIR "/README.md"};
  const std::filesystem::path docs = DSM_SOURCE_DIR "/docs";
  if (std::filesystem::is_directory(docs)) {
    for (const auto& entry : std::filesystem::directory_iterator(docs)) {
      if (entry.path().extension() == ".md") candidates.push_back(entry.path().string());
    }
  }
  std::map<std::string, std::string> documented;
  std::string problems, source;
  for (const std::string& candidate : candidates) {
    if (ReadParameterTable(candidate, &documented, &problems)) {
      source = candidate;
      break;
    }
  }
  ASSERT_FALSE(source.empty())
      << "no table with a header row '| Parameter | Default | ...' in README.md or docs/";
  for (const auto& [name, written] : documented) {
    const auto expected = NodeDefaults().find(name);
    if (expected == NodeDefaults().end()) {
      problems += "  " + name + ": not a parameter of the node\n";
    } else if (written == "required") {
      // No default: the node refuses to start without it (0 = not given).
      if (!expected->second.numeric || expected->second.number != 0.0) {
        problems += "  " + name + ": 'required', but the node's default is '" + expected->second.text + "'\n";
      }
    } else {
      problems += Mismatch(name, written, expected->second);
    }
  }
  for (const auto& entry : NodeDefaults()) {
    if (documented.count(entry.first) == 0) problems += "  " + entry.first + ": missing\n";
  }
  EXPECT_TRUE(problems.empty()) << "the parameter table of " << source << " disagrees with NodeParameters:\n"
                                << problems;
}

}  // namespace
}  // namespace ros_glue
}  // namespace deblur_sr_mvs
