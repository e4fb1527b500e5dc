#include "simstack/io/yaml_file.h"

#include <filesystem>
#include <fstream>
#include <iterator>
#include <map>
#include <sstream>
#include <stdexcept>
#include <vector>

#include "simstack/io/staged_output.h"

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
  // A directory opens as a stream and fails only on reading, with libstdc++'s own words.
  std::error_code ec;
  if (std::filesystem::is_directory(path, ec))
    throw std::runtime_error("cannot read " + what + " " + path +
                             ": it is a directory, not a YAML file");
  return checked(what, path, [&] { return YAML::LoadFile(path); });
}

YAML::Node parseYamlText(const std::string& text, const std::string& what,
                         const std::string& source) {
  return checked(what, source, [&] { return YAML::Load(text); });
}

std::string withTopLevelSection(const std::string& text, const std::string& key,
                                const std::string& section) {
  std::vector<std::string> lines;
  std::istringstream in(text);
  for (std::string line; std::getline(in, line);) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    lines.push_back(line);
  }
  auto comment_or_blank = [&](size_t i) { return lines[i].empty() || lines[i][0] == '#'; };
  size_t begin = lines.size(), end = lines.size();
  for (size_t i = 0; i < lines.size(); ++i) {
    if (lines[i].rfind(key + ":", 0) != 0) continue;
    begin = i;
    end = i + 1;
    while (end < lines.size() && (comment_or_blank(end) || lines[end][0] == ' ')) ++end;
    while (end < lines.size() && end > begin + 1 && comment_or_blank(end - 1)) --end;
    while (begin > 0 && lines[begin - 1].rfind('#', 0) == 0) --begin;
    break;
  }
  std::string out;
  for (size_t i = 0; i < begin; ++i) out += lines[i] + "\n";
  out += section;
  for (size_t i = end; i < lines.size(); ++i) out += lines[i] + "\n";
  return out;
}

void writeTopLevelSection(const std::string& path, const std::string& key,
                          const std::string& section, const std::string& what) {
  std::string old;
  if (std::ifstream in{path}) old.assign(std::istreambuf_iterator<char>(in), {});
  const std::string text = withTopLevelSection(old, key, section);
  const YAML::Node before =
      old.empty() ? YAML::Node(YAML::NodeType::Map) : parseYamlText(old, what, path);
  const YAML::Node after = parseYamlText(text, what, path);
  const YAML::Node wanted = parseYamlText(section, what + " section", key);
  auto same = [](const YAML::Node& a, const YAML::Node& b) {
    return YAML::Dump(a) == YAML::Dump(b);
  };
  bool ok = before.IsMap() && after.IsMap() && after.size() == before.size() + !before[key];
  ok = ok && same(after[key], wanted[key]);
  for (auto it = before.begin(); ok && it != before.end(); ++it) {
    const std::string k = it->first.as<std::string>();
    ok = k == key || same(after[k], it->second);
  }
  if (!ok)
    throw std::runtime_error("cannot put the " + key + ": section into " + what + " " + path +
                             " without changing the rest of it; edit it by hand");
  StagedFile staged(path);
  std::ofstream f(staged.path());
  f << text;
  f.close();
  if (!f) throw std::runtime_error("cannot write " + path);
  staged.commit();
}

void requireKnownKeys(const YAML::Node& map, const std::set<std::string>& known,
                      const std::string& where, const std::string& path) {
  for (const auto& kv : map) {
    const std::string key = kv.first.as<std::string>();
    if (!known.count(key))
      throw std::runtime_error(path + ": unknown key '" + key + "' in " + where);
  }
}

}  // namespace simstack
