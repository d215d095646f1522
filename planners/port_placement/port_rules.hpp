#pragma once
/// @file
/// The rules a port obeys, shared by the problem that makes plans and by the readers that check
/// them (`trocar check --plan`): how far the incision may lie from its site, how deep the pivot,
/// and where an instrument may touch the skin. docs/plan-format.md ("Ports") states them.

#include <Eigen/Core>
#include <algorithm>

namespace trocar::collision {
class TriangleBvh;
}

namespace trocar::planners {

/// A port's incision is at most this far from its site on the candidate curve (m).
constexpr double kMaxIncisionOffset = 0.06;
/// A pivot lies at most this deep under the skin (m).
constexpr double kMaxPivotDepth = 0.06;

/// The cannula's track through the chest wall (m): from the pivot between the ribs out to the
/// incision, or, when the incision is nearer than the skin straight above (it never is on a
/// sound plan), the pivot's depth under the skin. An instrument of the port may touch the skin
/// (the soft wall, which yields around the cannula) within this length plus the port radius of
/// the pivot: a trocar inserted obliquely runs through more wall than the depth straight down,
/// and the wall it runs through is where the cannula is.
inline double PortTrackLength(double pivot_depth, const Eigen::Vector3d& pivot,
                              const Eigen::Vector3d& incision) {
  return std::max(pivot_depth, (incision - pivot).norm());
}

/// The cannula's track as the instrument turns (docs/decisions.md, "the cannula's track"): the
/// remote centre is in the rib layer and the wall above it (fat, muscle, skin) is soft; an
/// instrument turned about its pivot carries the soft wall with its cannula, so its track runs
/// from the pivot out along its shaft to where the shaft leaves the skin *now*, not to where the
/// incision was cut. The skin end of the track may move at most the soft wall's own thickness (the
/// pivot's depth under the skin) from the incision: a shear of the wall of up to 45 degrees.
/// Returns the skin allowance of the port in this pose (m): the larger of the cut track's
/// (PortTrackLength + port_radius) and, when the shaft's skin crossing lies within that shift of
/// the incision, the pivot-to-crossing length + port_radius. All points in the skin mesh's frame;
/// `tip` is the instrument's tool tip (its shaft runs from the tip through the pivot); a tip within
/// 5 mm of the pivot gives no direction and the cut track's allowance.
double TrackAllowance(const collision::TriangleBvh& skin, double pivot_depth,
                      const Eigen::Vector3d& pivot, const Eigen::Vector3d& incision,
                      const Eigen::Vector3d& tip, double port_radius);

/// The contact rule at the target (docs/decisions.md, "contact rules"): an instrument's wrist and
/// jaws (collision::Body::distal) may touch the patient's structures other than the skin within
/// this distance of the target point they work on (m): the LAD lies on the heart, so grasping or
/// sewing it touches the heart there, and the LIMA lies on the chest wall's inner face. The
/// EndoWrist's jaws and wrist span about 1 cm; half a centimetre more for the tissue they press.
/// The shaft touching the heart, and the wrist touching it anywhere else, stay collisions.
constexpr double kWorkSiteRadius = 0.015;

/// An endoscope sees a target point only when the straight line from its camera to the point
/// crosses no patient structure (issue #41, item 5: a scope behind the heart does not see the
/// LAD), leaving out the line's last few millimetres: the point lies on a surface (the LAD on the
/// heart, the LIMA on the chest wall's inner face) and a line reaching it at a grazing angle runs
/// within the surface's own curvature there. 5 mm: the width of the vessel and the tissue beside
/// it that the surgeon looks at; a modelling choice, not a fitted value (docs/decisions.md).
constexpr double kSightMargin = 0.005;

}  // namespace trocar::planners
