#pragma once
/// @file config_fields.h
/// Reading a config section whose fields a function lists once, with their YAML names (the
/// model's and the trainer's configs): a field's value, and the refusal of fields the list does
/// not hold, so that a misspelt field is an error and not a default kept unnoticed.

#include <yaml-cpp/yaml.h>

#include <charconv>
#include <set>
#include <stdexcept>
#include <string>
#include <type_traits>

#include "simstack/io/yaml_file.h"

namespace simstack {

/// Reads `key` of `n` into `value` when present; `prefix` ("model.experimental.") names the
/// field in errors.
template <typename T>
void readConfigField(const YAML::Node& n, const char* key, T* value,
                     const std::string& prefix = "") {
  if (n[key]) *value = readYamlValue<T>(n[key], "field '" + prefix + key + "'");
}

/// YAML text of the config `section`; std::invalid_argument when it is not YAML.
inline YAML::Node parseConfigText(const std::string& text, const std::string& section) {
  try {
    return YAML::Load(text);
  } catch (const YAML::Exception& e) {
    throw std::invalid_argument(section + " config is not YAML: " + e.what());
  }
}

/// std::invalid_argument(what) unless `ok`.
inline void requireConfig(bool ok, const std::string& what) {
  if (!ok) throw std::invalid_argument(what);
}

/// A config value as the file writes it (0.0002, not 0.000200; a count as a whole number;
/// 0.0010000004 to the last digit that tells it from 0.001).
template <typename T>
std::string configValue(T v) {
  if constexpr (std::is_integral_v<T>) {
    return std::to_string(v);
  } else {
    char text[64];
    const std::to_chars_result r = std::to_chars(text, text + sizeof(text), static_cast<double>(v),
                                                 std::chars_format::general);
    return std::string(text, r.ptr);
  }
}

/// ", got V": the value a refusal names (configValue).
template <typename T>
std::string gotValue(T v) {
  return ", got " + configValue(v);
}

// A misspelt field in a file the user writes must not fall back to its default unnoticed
// (configs stored inside older model files are parsed leniently instead).
template <class C, class Fields>
void rejectUnknownFields(const YAML::Node& section, const std::string& name, Fields fields,
                         bool with_experimental) {
  if (!section.IsMap()) throw std::invalid_argument("'" + name + "' must be a map");
  C defaults;
  std::set<std::string> known;
  fields(defaults, [&](const char* key, const auto&) { known.insert(key); });
  if (with_experimental) known.insert("experimental");
  for (const auto& kv : section) {
    const std::string key = kv.first.as<std::string>();
    if (!known.count(key)) throw std::invalid_argument("unknown field " + name + "." + key);
  }
}

/// The `experimental:` map of the section `name` of a training file, its fields checked (an
/// empty map when there is none). A dropped variant's setting written outside it is refused
/// with the place it belongs.
template <class C, class Main, class Experimental>
YAML::Node experimentalOf(const YAML::Node& section, const std::string& name, Main main,
                          Experimental experimental) {
  if (!section.IsMap()) throw std::invalid_argument("'" + name + "' must be a map");
  C defaults;
  experimental(defaults, [&](const char* key, const auto&) {
    if (section[key])
      throw std::invalid_argument(name + "." + key + " is a dropped variant's setting: write it " +
                                  "under " + name + ".experimental");
  });
  rejectUnknownFields<C>(section, name, main, true);
  const YAML::Node x = section["experimental"];
  if (!x || x.IsNull()) return YAML::Node(YAML::NodeType::Map);
  rejectUnknownFields<C>(x, name + ".experimental", experimental, false);
  return x;
}

}  // namespace simstack
