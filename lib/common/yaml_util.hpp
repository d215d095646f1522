#pragma once
/// @file
/// Reading YAML with errors that name file, line, column and field path. Internal to
/// trocar (yaml-cpp is linked privately): include it only from .cpp files (lib/, planners/).

#include <yaml-cpp/yaml.h>

#include <Eigen/Core>
#include <initializer_list>
#include <string>
#include <vector>

namespace trocar {

class YamlReader {
 public:
  /// Parses `path`. @throws trocar::Error naming the file, line and column on a syntax error.
  static YamlReader Load(const std::string& path);

  const std::string& file() const { return file_; }
  const YAML::Node& root() const { return root_; }

  /// "file:line:col: path" for messages about `node`.
  std::string Where(const YAML::Node& node, const std::string& path) const;

  /// node[key], which must exist. @throws naming `path.key` when missing.
  YAML::Node Require(const YAML::Node& map, const std::string& key, const std::string& path) const;
  /// The node must be a map whose keys are all in `allowed` (catches typos).
  void ExpectMap(const YAML::Node& node, const std::string& path,
                 std::initializer_list<const char*> allowed) const;
  void ExpectMap(const YAML::Node& node, const std::string& path,
                 const std::vector<std::string>& allowed) const;
  void ExpectSequence(const YAML::Node& node, const std::string& path) const;

  /// A finite number; also accepts "pi/2", "-90 deg" and similar (ParseScalarExpression).
  /// Infinity (.inf) is refused: a size, threshold or weight is never infinite.
  double Number(const YAML::Node& node, const std::string& path) const;
  double NumberOr(const YAML::Node& map, const std::string& key, const std::string& path,
                  double fallback) const;
  /// A number or ±.inf: only for bounds that may be absent (joint limits).
  double Bound(const YAML::Node& node, const std::string& path) const;
  double BoundOr(const YAML::Node& map, const std::string& key, const std::string& path,
                 double fallback) const;
  std::string String(const YAML::Node& node, const std::string& path) const;
  bool Bool(const YAML::Node& node, const std::string& path) const;
  Eigen::Vector3d Vector3(const YAML::Node& node, const std::string& path) const;
  std::vector<double> Numbers(const YAML::Node& node, const std::string& path) const;
  std::vector<std::string> Strings(const YAML::Node& node, const std::string& path) const;

 private:
  YamlReader(std::string file, YAML::Node root) : file_(std::move(file)), root_(std::move(root)) {}
  std::string file_;
  YAML::Node root_;
};

}  // namespace trocar
