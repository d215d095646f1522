#pragma once
/// @file
/// Which arm reaches which stretch of each target, and which the endoscope sees (issue #43 item
/// 5), read from a plan of a plan file: by its verified motions when it was verified, else by its
/// own reach check (the claim). The report's table, the view's colours along the targets and
/// `trocar plan`'s lines all come from here.
///
/// A target's samples, in their order along it, are cut into stretches where any arm's status
/// changes: within a stretch every instrument either moves to every sample or to none, and the
/// endoscope sees every sample or none.

#include <Eigen/Core>
#include <cstddef>
#include <functional>
#include <string>
#include <vector>

#include "plan/plan_file.hpp"

namespace trocar::planners {

/// How far a target sample is served, for colouring along the target.
enum class ReachClass {
  kServed,  ///< every instrument moves there and an endoscope sees it (the verdict's "served")
  kPartly,  ///< some instrument moves there, or all do but no endoscope sees it
  kNone,    ///< no instrument moves there
};

/// One arm over one stretch.
struct ArmOnStretch {
  std::string arm;
  bool endoscope = false;
  /// An instrument: its motion (verified) or reach (claimed) succeeds at every sample of the
  /// stretch; an endoscope: it sees every sample.
  bool reaches = false;
  /// When not: the most common reason among the stretch's samples ("in collision: psm1's shaft
  /// against the heart"), as the plan file gives it.
  std::string why_not;
};

struct TargetStretch {
  std::string target;
  std::vector<int> samples;              ///< indices into PlanFile::samples, along the target
  double from_m = 0.0, to_m = 0.0;       ///< the samples' arc lengths from the target's first point
  double length_m = 0.0;                 ///< the target's last sample's arc length
  std::vector<ArmOnStretch> arms;        ///< in the plan file's arm order
  bool served = false;                   ///< every sample of the stretch served
  ReachClass reach = ReachClass::kNone;  ///< the same for every sample of the stretch
  /// Where the stretch lies in a surgeon's terms ("at the 3rd to 4th intercostal spaces"), from
  /// the caller's `level`; empty without.
  std::string level;
};

struct Reachability {
  bool verified = false;  ///< from verified motions (else from the plan's own reach check)
  std::vector<ReachClass> per_sample;    ///< indexed as PlanFile::samples
  std::vector<TargetStretch> stretches;  ///< targets in their first sample's order
};

/// The level of a stretch in a surgeon's terms from its samples' world points ("3rd to 4th
/// intercostal spaces"), or "" when it cannot be said.
using LevelText = std::function<std::string(const std::vector<Eigen::Vector3d>& p_W)>;

/// The reachability of plan `index` (0-based) of `file`. @throws trocar::Error when the index is
/// out of range, or a motion or reach names a sample or arm the file does not have.
Reachability TargetReachability(const PlanFile& file, std::size_t index,
                                const LevelText& level = {});
/// The same for a plan of the file that is not among its ranked plans (a baseline's).
Reachability TargetReachability(const PlanFile& file, const StoredPlan& plan,
                                const LevelText& level = {});

/// Where a stretch lies along its target, whose points run from its proximal end (a vessel's
/// origin; the LIMA from the first rib) and whose samples reach `length_m`: "12–48 mm from its
/// first point (its proximal third)", one number for a one-sample stretch; the thirds (proximal,
/// middle, distal) are the surgeon's words for a vessel's segments.
std::string AlongTarget(double from_m, double to_m, double length_m);
/// AlongTarget of the stretch.
std::string StretchText(const TargetStretch& stretch);

}  // namespace trocar::planners
