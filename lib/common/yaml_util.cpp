#include "common/yaml_util.hpp"

#include <cmath>
#include <cstdint>
#include <map>
#include <sstream>

#include "common/error.hpp"
#include "common/file_util.hpp"
#include "common/geometry.hpp"
#include "common/limits.hpp"

namespace trocar {

namespace {

std::string At(const std::string& file, const YAML::Mark& mark) {
  std::ostringstream out;
  out << file;
  if (mark.line >= 0) out << ":" << mark.line + 1 << ":" << mark.column + 1;
  return out.str();
}

// Every mapping key is a plain scalar and appears once: yaml-cpp keeps the first of duplicate
// keys without a word (so an edit further down a file would silently not apply), and a key that
// is a list or mapping cannot name a field. The walk is bounded in nodes: aliases can make a
// small file a huge tree.
void CheckKeys(const YAML::Node& node, const std::string& file, const std::string& path,
               std::uint64_t* walked) {
  const std::uint64_t limit = Limits().max_yaml_nodes;
  TROCAR_THROW_UNLESS(++*walked <= limit,
                      file << ": more than " << limit
                           << " YAML nodes (aliases expanding?) " << LimitHint(limit, "TROCAR_MAX_YAML_NODES"));
  if (node.IsSequence()) {
    for (std::size_t i = 0; i < node.size(); ++i) {
      CheckKeys(node[i], file, path + "[" + std::to_string(i) + "]", walked);
    }
  } else if (node.IsMap()) {
    std::map<std::string, YAML::Mark> seen;
    for (const auto& entry : node) {
      TROCAR_THROW_UNLESS(entry.first.IsScalar(),
                          At(file, entry.first.Mark())
                              << ": " << (path.empty() ? "top level" : path)
                              << ": a key must be a plain name, not a "
                              << (entry.first.IsSequence() ? "list" : entry.first.IsMap() ? "mapping" : "null"));
      const std::string key = entry.first.Scalar();
      const auto [it, fresh] = seen.emplace(key, entry.first.Mark());
      TROCAR_THROW_UNLESS(fresh, At(file, entry.first.Mark())
                                     << ": " << (path.empty() ? "" : path + ".") << key
                                     << ": duplicate key (first at line " << it->second.line + 1
                                     << "; only one may be given)");
      CheckKeys(entry.second, file, path.empty() ? key : path + "." + key, walked);
    }
  }
}

}  // namespace

YamlReader YamlReader::Load(const std::string& path) {
  const std::string text = ReadTextFile(path);
  YAML::Node root;
  try {
    root = YAML::Load(text);
  } catch (const YAML::Exception& e) {
    TROCAR_THROW(path << ":" << e.mark.line + 1 << ":" << e.mark.column + 1
                      << ": YAML syntax error: " << e.msg);
  }
  TROCAR_THROW_UNLESS(root.IsMap(), path << ": expected a YAML mapping at the top level");
  std::uint64_t walked = 0;
  try {
    CheckKeys(root, path, "", &walked);
  } catch (const YAML::Exception& e) {
    TROCAR_THROW(path << ":" << e.mark.line + 1 << ":" << e.mark.column + 1 << ": " << e.msg);
  }
  return YamlReader(path, root);
}

std::string YamlReader::Where(const YAML::Node& node, const std::string& path) const {
  std::ostringstream out;
  out << file_;
  const YAML::Mark mark = node.Mark();
  if (mark.line >= 0) out << ":" << mark.line + 1 << ":" << mark.column + 1;
  if (!path.empty()) out << ": " << path;
  return out.str();
}

YAML::Node YamlReader::Require(const YAML::Node& map, const std::string& key,
                               const std::string& path) const {
  TROCAR_THROW_UNLESS(map.IsMap(), Where(map, path) << ": expected a mapping");
  const YAML::Node value = map[key];
  TROCAR_THROW_UNLESS(value.IsDefined() && !value.IsNull(),
                      Where(map, path) << ": missing field '" << key << "'");
  return value;
}

void YamlReader::ExpectMap(const YAML::Node& node, const std::string& path,
                           std::initializer_list<const char*> allowed) const {
  ExpectMap(node, path, std::vector<std::string>(allowed.begin(), allowed.end()));
}

void YamlReader::ExpectMap(const YAML::Node& node, const std::string& path,
                           const std::vector<std::string>& allowed) const {
  TROCAR_THROW_UNLESS(node.IsMap(), Where(node, path) << ": expected a mapping");
  for (const auto& entry : node) {
    const std::string key = entry.first.as<std::string>();
    bool known = false;
    for (const std::string& a : allowed) known = known || key == a;
    if (!known) {
      std::string expected;
      for (const std::string& a : allowed) expected += (expected.empty() ? "" : ", ") + a;
      TROCAR_THROW(Where(entry.first, path) << ": unknown field '" << key
                                            << "' (expected one of: " << expected << ")");
    }
  }
}

void YamlReader::ExpectSequence(const YAML::Node& node, const std::string& path) const {
  TROCAR_THROW_UNLESS(node.IsSequence(), Where(node, path) << ": expected a list");
}

double YamlReader::Bound(const YAML::Node& node, const std::string& path) const {
  TROCAR_THROW_UNLESS(node.IsScalar(), Where(node, path) << ": expected a number");
  const std::string text = node.Scalar();
  if (text == ".inf" || text == "inf" || text == ".Inf" || text == "+.inf") return HUGE_VAL;
  if (text == "-.inf" || text == "-inf" || text == "-.Inf") return -HUGE_VAL;
  return Number(node, path);
}

double YamlReader::BoundOr(const YAML::Node& map, const std::string& key, const std::string& path,
                           double fallback) const {
  const YAML::Node value = map[key];
  if (!value.IsDefined() || value.IsNull()) return fallback;
  return Bound(value, path + "." + key);
}

double YamlReader::Number(const YAML::Node& node, const std::string& path) const {
  TROCAR_THROW_UNLESS(node.IsScalar(), Where(node, path) << ": expected a number");
  const std::string text = node.Scalar();
  double value = 0.0;
  TROCAR_THROW_UNLESS(ParseScalarExpression(text, &value),
                      Where(node, path) << ": expected a number (or pi/2, 90 deg), got '" << text
                                        << "'");
  TROCAR_THROW_UNLESS(std::isfinite(value), Where(node, path) << ": value '" << text
                                                              << "' is not finite");
  return value;
}

double YamlReader::NumberOr(const YAML::Node& map, const std::string& key,
                            const std::string& path, double fallback) const {
  const YAML::Node value = map[key];
  if (!value.IsDefined() || value.IsNull()) return fallback;
  return Number(value, path + "." + key);
}

std::string YamlReader::String(const YAML::Node& node, const std::string& path) const {
  TROCAR_THROW_UNLESS(node.IsScalar(), Where(node, path) << ": expected a string");
  return node.Scalar();
}

bool YamlReader::Bool(const YAML::Node& node, const std::string& path) const {
  TROCAR_THROW_UNLESS(node.IsScalar(), Where(node, path) << ": expected true or false");
  const std::string& s = node.Scalar();
  if (s == "true" || s == "True" || s == "yes") return true;
  if (s == "false" || s == "False" || s == "no") return false;
  TROCAR_THROW(Where(node, path) << ": expected true or false, got '" << s << "'");
}

Eigen::Vector3d YamlReader::Vector3(const YAML::Node& node, const std::string& path) const {
  TROCAR_THROW_UNLESS(node.IsSequence() && node.size() == 3,
                      Where(node, path) << ": expected a list of 3 numbers");
  Eigen::Vector3d v;
  for (int i = 0; i < 3; ++i) v[i] = Number(node[i], path + "[" + std::to_string(i) + "]");
  return v;
}

std::vector<double> YamlReader::Numbers(const YAML::Node& node, const std::string& path) const {
  ExpectSequence(node, path);
  std::vector<double> values;
  for (std::size_t i = 0; i < node.size(); ++i) {
    values.push_back(Number(node[i], path + "[" + std::to_string(i) + "]"));
  }
  return values;
}

std::vector<std::string> YamlReader::Strings(const YAML::Node& node,
                                             const std::string& path) const {
  ExpectSequence(node, path);
  std::vector<std::string> values;
  for (std::size_t i = 0; i < node.size(); ++i) {
    values.push_back(String(node[i], path + "[" + std::to_string(i) + "]"));
  }
  return values;
}

}  // namespace trocar
