#pragma once
/// @file yaml_file.h
/// YAML a person may edit (perception and training configs, model cards, view descriptions,
/// superquadric files). yaml-cpp keeps a key written twice in one map and answers a lookup with
/// its first value, so a section appended below an older one of the same name would be silently
/// ignored; here it is an error.

#include <yaml-cpp/yaml.h>

#include <array>
#include <cmath>
#include <set>
#include <stdexcept>
#include <string>
#include <type_traits>

namespace simstack {

/// Parses the file; throws std::runtime_error "cannot read <what> <path>: ..." when it cannot
/// be read or parsed, or when a map repeats a key (naming the key, its path and both lines).
YAML::Node loadYamlFile(const std::string& path, const std::string& what);
/// The same for text; `source` names it in the error.
YAML::Node parseYamlText(const std::string& text, const std::string& what,
                         const std::string& source);

/// Throws std::runtime_error "<path>: unknown key '<key>' in <where>" for the first key of `map`
/// that is none of `known`: a misspelt field is an error, not a default silently kept.
void requireKnownKeys(const YAML::Node& map, const std::set<std::string>& known,
                      const std::string& where, const std::string& path);

/// What a value of type T is, for errors ("a number", "a list of 3 numbers").
template <typename T>
std::string yamlTypeName() {
  if constexpr (std::is_same_v<T, bool>) return "true or false";
  if constexpr (std::is_integral_v<T>) return "a whole number";
  if constexpr (std::is_floating_point_v<T>) return "a number";
  if constexpr (std::is_same_v<T, std::string>) return "a string";
  if constexpr (std::is_same_v<T, std::array<double, 3>>) return "a list of 3 numbers";
  return "a value of its kind";
}

/// `node` read as T, `field` ("hough.radius_m") naming it in the error: std::invalid_argument
/// "<field>: <the value> (line L, column C) is not <what T is>", or "<field>: <text> is not a
/// finite number" for a number at infinity or NaN (no scalar field means either; lists such as the
/// workspace box's corners may hold .inf and are not checked here).
template <typename T>
T readYamlValue(const YAML::Node& node, const std::string& field) {
  T value{};
  try {
    value = node.as<T>();
  } catch (const YAML::Exception&) {
    YAML::Emitter flow;
    flow << YAML::Flow << node;
    std::string text = flow.c_str();
    if (text.size() > 60) text = text.substr(0, 57) + "...";
    const bool quoted = node.IsScalar() && node.Tag() == "!";  // a string, as quoted
    const YAML::Mark at = node.Mark();
    throw std::invalid_argument(field + ": " + (quoted ? "the string " : "") + text +
                                (at.is_null()
                                     ? std::string()
                                     : " (line " + std::to_string(at.line + 1) + ", column " +
                                           std::to_string(at.column + 1) + ")") +
                                " is not " + yamlTypeName<T>());
  }
  if constexpr (std::is_floating_point_v<T>)
    if (!std::isfinite(value))
      throw std::invalid_argument(field + ": " + node.Scalar() + " is not a finite number");
  return value;
}

/// `text` (YAML with comments) with its top-level section `key` (the line `key:` down to the
/// next top-level key, less the comments and blank lines just above that, plus the comments
/// just above the section) replaced by `section`, every other line kept; `section` is appended
/// when the text has none. Line ends are written as \n.
std::string withTopLevelSection(const std::string& text, const std::string& key,
                                const std::string& section);
/// The file `path` (`what`: "model card") with its section `key` replaced by `section` (YAML
/// text holding `key:` alone), written whole or not at all; a file that does not exist is
/// created holding the section. The result is read back first: its `key` must be the section's
/// and every other top-level entry the file's own, or the file is left as it was and
/// std::runtime_error says to edit it by hand.
void writeTopLevelSection(const std::string& path, const std::string& key,
                          const std::string& section, const std::string& what);

}  // namespace simstack
