#pragma once
/// @file yaml_file.h
/// YAML a person may edit (perception and training configs, model cards, view descriptions,
/// superquadric files). yaml-cpp keeps a key written twice in one map and answers a lookup with
/// its first value, so a section appended below an older one of the same name would be silently
/// ignored; here it is an error.

#include <yaml-cpp/yaml.h>

#include <string>

namespace simstack {

/// Parses the file; throws std::runtime_error "cannot read <what> <path>: ..." when it cannot
/// be read or parsed, or when a map repeats a key (naming the key, its path and both lines).
YAML::Node loadYamlFile(const std::string& path, const std::string& what);
/// The same for text; `source` names it in the error.
YAML::Node parseYamlText(const std::string& text, const std::string& what,
                         const std::string& source);

}  // namespace simstack
