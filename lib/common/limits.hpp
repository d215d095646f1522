#pragma once
/// @file
/// Limits on what one input may cost: bytes read from a file, voxels in a volume, bytes a
/// compressed stream inflates to, XML nesting, robot includes, YAML nodes, recorded samples.
/// Every reader checks its limit before it allocates and names the file, the limit and how to
/// raise it. Defaults fit a clinical CT and a robot of a few hundred links with room to spare;
/// a user who needs more sets the environment variable named with each field (read once).

#include <cstdint>
#include <string>

#include <Eigen/Core>

namespace trocar {

struct InputLimits {
  std::uint64_t max_file_bytes = 4ull << 30;  ///< TROCAR_MAX_FILE_BYTES: one binary file (CT)
  std::uint64_t max_text_bytes = 256ull << 20;  ///< TROCAR_MAX_TEXT_BYTES: YAML, JSON, URDF, CSV
  /// TROCAR_MAX_VOXELS: one volume; 512 × 512 × 1024 (1 GiB as float; the import needs several
  /// times that in masks and surfaces)
  std::uint64_t max_voxels = 1ull << 28;
  int max_xml_depth = 64;                     ///< TROCAR_MAX_XML_DEPTH: URDF element nesting
  int max_includes = 256;                     ///< TROCAR_MAX_INCLUDES: robot files per load
  std::uint64_t max_yaml_nodes = 2000000;     ///< TROCAR_MAX_YAML_NODES: nodes walked per file
  /// TROCAR_MAX_JSON_VALUES: values in one JSON file (a verified plan holds about 10,000; two
  /// million keep the parsed document near 200 MB whatever the text)
  std::uint64_t max_json_values = 2000000;
  int max_json_depth = 64;                    ///< TROCAR_MAX_JSON_DEPTH: JSON nesting
  /// TROCAR_MAX_JSON_STRING: bytes in one JSON string or key (a plan's longest, a message with
  /// its collision pairs, is a few hundred)
  std::uint64_t max_json_string = 65536;
  /// TROCAR_MAX_RECORDED_SAMPLES: rows a teleop record keeps (~200 MB); longer runs are thinned
  std::uint64_t max_recorded_samples = 500000;
};

/// The process's limits: the defaults, overridden by the environment variables above.
/// @throws trocar::Error naming the variable when one is set to something not a positive integer.
const InputLimits& Limits();

/// Replaces the limits for the rest of the process (tests; a command-line option).
void SetLimits(const InputLimits& limits);

/// "(limit N, set ENV to raise it)" for messages.
std::string LimitHint(std::uint64_t limit, const char* env);

/// Product of three sizes, each positive, without overflow; refused beyond `Limits().max_voxels`.
/// @throws trocar::Error naming `what` and the sizes.
std::uint64_t CheckedVoxelCount(const Eigen::Vector3i& size, const std::string& what);

}  // namespace trocar
