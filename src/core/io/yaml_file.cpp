#include "simstack/io/yaml_file.h"

#include <map>
#include <stdexcept>

namespace simstack {
namespace {

// Throws on the first map (at any depth) holding a key twice; `where` is the key path so far.
void rejectRepeatedKeys(const YAML::Node& node, const std::string& where) {
  if (node.IsSequence()) {
    for (size_t i = 0; i < node.size(); ++i)
      rejectRepeatedKeys(node[i], where + "[" + std::to_string(i) + "]");
    return;
  }
  if (!node.IsMap()) return;
  std::map<std::string, int> first_line;
  for (const auto& kv : node) {
    const std::string key = kv.first.Scalar();
    const std::string path = where.empty() ? key : where + "." + key;
    const int line = kv.first.Mark().line + 1;
    const auto [it, fresh] = first_line.emplace(key, line);
    if (!fresh)
      throw std::runtime_error("key '" + path + "' appears twice (lines " +
                               std::to_string(it->second) + " and " + std::to_string(line) +
                               "); merge the two");
    rejectRepeatedKeys(kv.second, path);
  }
}

YAML::Node checked(const std::string& what, const std::string& source,
                   YAML::Node (*parse)(const std::string&), const std::string& argument) {
  try {
    YAML::Node root = parse(argument);
    rejectRepeatedKeys(root, "");
    return root;
  } catch (const std::exception& e) {
    throw std::runtime_error("cannot read " + what + " " + source + ": " + e.what());
  }
}

}  // namespace

YAML::Node loadYamlFile(const std::string& path, const std::string& what) {
  return checked(
      what, path, [](const std::string& p) { return YAML::LoadFile(p); }, path);
}

YAML::Node parseYamlText(const std::string& text, const std::string& what,
                         const std::string& source) {
  return checked(
      what, source, [](const std::string& t) { return YAML::Load(t); }, text);
}

}  // namespace simstack
