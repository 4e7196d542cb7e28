// The JSON files the tools write (report.json and kin), through nlohmann-json:
// keys in the order written, non-finite numbers as null, strings escaped.
#pragma once

#include <cmath>
#include <string>

#include <nlohmann/json.hpp>

namespace deblur_sr_mvs {

using Json = nlohmann::ordered_json;  // keeps the keys in the order they are added

// A number, or null when it is not finite (JSON has no NaN or infinity).
inline Json JsonNumber(double value) {
  return std::isfinite(value) ? Json(value) : Json(nullptr);
}

// The file text: indented by 2, ending in a newline. Bytes that are not UTF-8
// (a path in another encoding) become U+FFFD instead of failing the write.
inline std::string JsonText(const Json& json) {
  return json.dump(2, ' ', false, Json::error_handler_t::replace) + "\n";
}

}  // namespace deblur_sr_mvs
