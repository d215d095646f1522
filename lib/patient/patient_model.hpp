#pragma once
/// @file
/// The patient model the planners, the collision world and the viewer share: surfaces of the
/// structures (skin, ribs, sternum, spine, heart), targets with surface normals, port candidate
/// curves, and the patient's pose on the operating table. Immutable once built; built from a case
/// folder (`patients/<case>/patient.yaml`) and cached beside it.

#include <functional>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Geometry>

#include "common/mesh.hpp"
#include "patient/curve.hpp"
#include "patient/operative_state.hpp"

namespace trocar::patient {

/// A segmented structure's surface in the patient frame P (m).
struct Structure {
  std::string name;        ///< "skin", "ribs", "sternum", "spine", "heart"
  TriangleMesh mesh;
  double volume = 0.0;     ///< m³ of the mask it came from
  long contoured_triangles = 0;  ///< before decimation
};

/// A target (LAD, LIMA, any named target): points in P with unit normals along which an
/// instrument should approach it (the thesis' cones, fig. 2.10).
struct Target {
  std::string name;
  Curve points;
  std::vector<Eigen::Vector3d> normals;
  std::string normals_from;  ///< "file" or "surface:<structure>"
};

/// A curve on the skin along which a port may be placed.
struct PortCandidate {
  std::string name;
  Curve skin;                ///< points on the skin, in P (m)
  std::string source;        ///< "markups:<file>" (annotated) or "intercostal" (found)
};

/// The operating table: a box whose top is at `height` in the world frame W (z up), long axis
/// along x_W, centred on the origin.
struct Table {
  double height = 0.80, width = 0.52, length = 2.0, thickness = 0.06;  ///< m
};

struct PatientModel {
  std::string name;
  std::string case_dir;
  std::vector<Structure> structures;
  std::vector<Target> targets;
  std::vector<PortCandidate> port_candidates;
  Table table;
  /// Pose of the patient (CT) frame in the world: supine, head toward +x_W, the left side raised
  /// by `left_side_up` about the body axis, resting on the table top.
  Eigen::Isometry3d X_WP = Eigen::Isometry3d::Identity();
  double left_side_up = 0.0;  ///< rad
  Eigen::Vector3d body_min_P = Eigen::Vector3d::Zero(), body_max_P = Eigen::Vector3d::Zero();
  std::string ct_source;      ///< the CT it was built from
  /// The state the model is in (operative_state.hpp): the CT's, or the operation's (the heart and
  /// the targets on it moved), and what that moved. Set by ImportCase after the cached build.
  OperativeState operation = OperativeState::CtState();
  OperativeChange operative_change;
  /// Faces of the scan's box the body is cut by ("superior", "left", ...): the skin there is a
  /// crop face; no port candidate lies within `kCutFaceMargin` of one.
  std::vector<std::string> cut_faces;
  static constexpr double kCutFaceMargin = 0.015;  ///< m

  const Structure* Find(const std::string& name) const;
  long triangle_count() const;
};

/// What one import did and found, beside the model: the model is the patient (geometry and
/// clinical content, the same whichever way it was built); the report is about this build of it.
struct ImportReport {
  /// Time per build stage (s), in order; on a cached load, a single "load cache" entry.
  std::vector<std::pair<std::string, double>> timings;
  bool from_cache = false;
  std::string cache_error;  ///< why the cache could not be written (the model itself is whole)
  /// What the import checked and found (orientation from anatomy, the bone sorting, the ribs'
  /// numbering, cut faces), a line each.
  std::vector<std::string> checks;
  /// What a user must know before trusting the model (a doubtful orientation, port candidates cut
  /// at the scan's edge, no heart, no port candidates), a line each.
  std::vector<std::string> warnings;
};

/// An imported patient: the model, immutable and shared by whatever plans on it, and the report.
struct ImportedPatient {
  /// In the operation's state (patient.yaml `operation:`, defaults from the literature) unless
  /// ImportOptions::ct_state.
  std::shared_ptr<const PatientModel> model;
  /// The same patient in the CT's state (what the scan shows), for showing beside the model.
  std::shared_ptr<const PatientModel> ct_model;
  ImportReport report;
};

struct ImportOptions {
  bool use_cache = true;   ///< read `cache/model.bin` when its key matches the inputs
  bool write_cache = true;
  /// The model in the CT's state: the operative state (patient.yaml `operation:`) not applied.
  bool ct_state = false;
  /// Called with each stage's name as it starts ("load CT", "segment body and bone", ...), from
  /// the calling thread (progress on a terminal).
  std::function<void(const std::string&)> progress;
};

/// Reads `case_dir/patient.yaml`, builds (or loads from the cache) the model: CT import,
/// segmentation, heart (mask or contrast), surfaces within their triangle budgets, targets with
/// normals (from the markups' orientations or the nearest surface), port candidates (annotated
/// curves, else intercostal spaces found from the ribs), pose on the table; then the operative
/// state (operative_state.hpp) is applied to a copy (not cached: it is cheap). A phantom case whose
/// CT is missing is generated first. The cache (`case_dir/cache/`: model.bin, one STL per
/// structure, ports and targets as markups) is keyed by the contents of every input file.
/// @throws trocar::Error naming the file and field for bad input.
ImportedPatient ImportCase(const std::string& case_dir, const ImportOptions& options = {});

/// The model alone (a copy), for callers that need no report.
PatientModel ImportPatient(const std::string& case_dir, const ImportOptions& options = {});

/// Surface normal of `mesh` nearest to `p_P` (area-weighted vertex normal, outward).
Eigen::Vector3d NearestSurfaceNormal(const TriangleMesh& mesh, const Eigen::Vector3d& p_P);

/// X_WP for a patient whose skin is `skin` (P frame), raised on its left by `left_side_up`, its
/// lowest skin point on the table top, centred over the table.
Eigen::Isometry3d PoseOnTable(const TriangleMesh& skin, double left_side_up, const Table& table);

/// Serialisation of a model (binary, versioned, with the input key). Load returns false on any
/// mismatch or corruption (the caller rebuilds), never a half-read model. The file carries a
/// checksum of its whole contents; `damage` says why a file that is not merely stale (built from
/// other inputs) was refused: truncated, checksum failed, inconsistent.
/// The report's checks and warnings travel with the model (a cached load reports them again).
std::string SerializeModel(const PatientModel& model, const ImportReport& report, std::uint64_t key);
bool DeserializeModel(const std::string& bytes, std::uint64_t key, PatientModel* model, ImportReport* report,
                      std::string* damage = nullptr);

}  // namespace trocar::patient
