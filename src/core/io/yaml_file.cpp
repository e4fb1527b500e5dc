#include "simstack/io/yaml_file.h"

#include <map>
#include <stdexcept>

namespace simstack {
namespace {

// "lines 3 and 7", or "line 3, columns 2 and 9" for a map on one line (1-based, as editors count).
std::string place(const YAML::Mark& a, const YAML::Mark& b) {
  if (a.line != b.line)
    return "lines " + std::to_string(a.line + 1) + " and " + std::to_string(b.line + 1);
  return "line " + std::to_string(a.line + 1) + ", columns " + std::to_string(a.column + 1) +
         " and " + std::to_string(b.column + 1);
}

// Throws on the first map (at any depth) holding a key twice; `where` is the key path so far.
void rejectRepeatedKeys(const YAML::Node& node, const std::string& where) {
  if (node.IsSequence()) {
    for (size_t i = 0; i < node.size(); ++i)
      rejectRepeatedKeys(node[i], where + "[" + std::to_string(i) + "]");
    return;
  }
  if (!node.IsMap()) return;
  std::map<std::string, YAML::Mark> first;
  for (const auto& kv : node) {
    if (!kv.first.IsScalar()) continue;  // a list or map as a key: left to the reader
    const std::string key = kv.first.Scalar();
    const std::string path = where.empty() ? key : where + "." + key;
    const auto [it, fresh] = first.emplace(key, kv.first.Mark());
    if (!fresh)
      throw std::runtime_error("key '" + path + "' appears twice (" +
                               place(it->second, kv.first.Mark()) + "); merge the two");
    rejectRepeatedKeys(kv.second, path);
  }
}

template <class Parse>
YAML::Node checked(const std::string& what, const std::string& source, Parse parse) {
  try {
    YAML::Node root = parse();
    rejectRepeatedKeys(root, "");
    return root;
  } catch (const std::runtime_error& e) {  // YAML::Exception is one
    throw std::runtime_error("cannot read " + what + " " + source + ": " + e.what());
  }
}

}  // namespace

YAML::Node loadYamlFile(const std::string& path, const std::string& what) {
  return checked(what, path, [&] { return YAML::LoadFile(path); });
}

YAML::Node parseYamlText(const std::string& text, const std::string& what,
                         const std::string& source) {
  return checked(what, source, [&] { return YAML::Load(text); });
}

}  // namespace simstack
