#pragma once
/// @file
/// Ports chosen by someone other than the optimiser, placed on this patient so that they can be
/// scored and verified exactly as the optimiser's plans are (issue #41, item 3; Cannon et al. 2003
/// compared their planned ports with a published template and with the surgeons' own):
///  - a published port template in anatomical terms (intercostal space, chest-wall line), placed
///    from this patient's numbered spaces and skin (docs/port-templates.md gives the template,
///    its source and the lines' definitions);
///  - a surgeon's own ports, a 3D Slicer point list with one point per arm labelled with the
///    arm's name.
/// Both become PortSites on the patient's port candidates (the middle of an intercostal space), as
/// the optimiser's ports are; the cart's pose is then searched for them (PlanFixedPorts,
/// optimizer.hpp).

#include <limits>
#include <string>
#include <vector>

#include "port_placement/problem.hpp"

namespace trocar::planners {

/// The vertical reference lines of the chest wall at one axial level, as lateral offsets from
/// the midline toward one side (m). Operational definitions on the CT's skin (the surface
/// anatomy's lines are defined on the living body by the clavicle and the axillary folds, which a
/// CT of the chest does not show reliably), docs/port-templates.md:
///  - midline: the sternum's centre (the body's centre left-right without a sternum);
///  - mid-axillary line (MAL): the most lateral point of the chest's skin at that level (arms
///    beside the chest excluded: skin facing outward within 8 cm of the ribs);
///  - anterior axillary line (AAL): where the skin turns from the front to the side, its outward
///    normal 45 degrees between anterior and lateral (the median over the level's skin);
///  - midclavicular line (MCL): halfway from the midline to the MAL (the clavicle's middle).
struct ChestLines {
  int side = 1;           ///< +1 left, -1 right
  double z_P = 0.0;       ///< the level (patient frame, m)
  double midline_x = 0.0; ///< patient frame x of the midline (m)
  double mcl = 0.0, aal = 0.0, mal = 0.0;  ///< lateral offsets (m)
  /// The sternum's edge on that side at that level (its outermost point within 15 mm of the
  /// level), as a lateral offset (m); NaN when the model has no sternum there (below the xiphoid,
  /// or none found).
  double sternal_edge = std::numeric_limits<double>::quiet_NaN();
};

/// @throws trocar::Error when the patient has no skin, or the skin at that level has no lateral
///         or anterolateral face (a level outside the scan).
ChestLines ChestLinesAt(const patient::PatientModel& patient, int side, double z_P);

/// A port in a surgeon's terms: its space and where across the chest its incision lies, by the
/// nearest of the chest's lines at its level, and its distances from the midline and the sternal
/// edge (where the sternum reaches that level): "ICS-L3, 14 mm lateral of the midclavicular line
/// (102 mm from the midline, 82 mm from the sternal edge)". Just the space's name when the lines
/// cannot be read (no skin).
std::string DescribePort(const patient::PatientModel& patient, const PortSite& site);

/// The intercostal space at the level of a point (patient frame): the number of the named space
/// (candidate "ICS-L3", "ICS-R3") whose curve passes nearest the point; 0 when no candidate is
/// named by number (ribs not numbered). For stretches of a target in a surgeon's terms.
int SpaceAtLevel(const patient::PatientModel& patient, const Eigen::Vector3d& p_P);

/// "3rd intercostal space", "1st to 2nd intercostal spaces"; "" when `first` is 0.
std::string SpacesText(int first, int last);

/// The spaces at the level of points in the world (a target's stretch), as SpacesText gives them:
/// from the lowest to the highest SpaceAtLevel of the points; "" when none is named.
std::string SpacesAtLevel(const patient::PatientModel& patient,
                          const std::vector<Eigen::Vector3d>& p_W);

/// A port of a template: which arm role, which intercostal space, where along it.
struct TemplatePort {
  ArmRole role = ArmRole::kInstrument;
  int space = 0;  ///< intercostal space number (below rib `space`)
  /// Where across the chest: 0 on the midclavicular line, 1 on the anterior axillary line,
  /// 0.5 midway (the offset interpolated between the two lines).
  double between_mcl_aal = 1.0;
  std::string where;  ///< "5th intercostal space, anterior axillary line"
};

struct PortTemplate {
  std::string name;    ///< "tecab"
  std::string title;   ///< "robotic TECAB (Bonatti et al.)"
  std::string source;  ///< the citation
  int side = 1;        ///< +1: the left chest
  std::vector<TemplatePort> ports;
};

/// The published template for robotic TECAB on the da Vinci: the endoscope in the 5th space on
/// the anterior axillary line, the instruments in the 3rd and 7th spaces midway between the
/// anterior axillary and midclavicular lines (Bonatti, Hasan, Prud'Homme, Mick, "Robotic CABG",
/// in Sellke (ed.), Atlas of Cardiac Surgical Techniques, ch. 7; the same spaces for robotic
/// LITA harvest, Kiaii et al., ibid. ch. 6).
PortTemplate TecabTemplate();

/// Ports placed for the problem's arms (one site per arm, in the problem's arm order) and how.
struct FixedPorts {
  std::string kind;  ///< "template" or "surgeon"
  std::string name;  ///< the template's title, or the ports file
  std::string source;
  std::vector<PortSite> sites;
  /// Per arm: where its port is, in the terms it was given ("ICS-L5 on the anterior axillary
  /// line", "point 'psm1', 3 mm from the middle of ICS-L4").
  std::vector<std::string> where;
  std::vector<std::string> notes;  ///< what was approximated (a line beyond a space's end)
};

/// The template placed on the patient: one FixedPorts per way of giving its instrument ports to
/// the problem's instrument arms (both are tried: which hand takes the upper port is the team's
/// choice at docking), the arms' order first.
/// @throws trocar::Error when a space it needs is not named on the patient (ribs not numbered:
///         the message lists the spaces found and says how to count them, `intercostal:
///         {count_from: N}`), or the problem's arms do not match its ports by role.
std::vector<FixedPorts> PlaceTemplate(const PortPlacementProblem& problem,
                                      const PortTemplate& port_template);

/// A surgeon's ports from a 3D Slicer point list (`.mrk.json`; the first point list in the
/// file), one point per arm labelled with the arm's name (or its RCM frame), in the patient's
/// frame. Each point is taken to the nearest point of the middle of an intercostal space (a
/// port candidate).
/// @throws trocar::Error naming the file and the point: an arm without a point, a label that is
///         no arm, two points for one arm, a point off the skin (more than 2 cm from it: another
///         patient's frame?), a point far from every space.
FixedPorts ReadPortsFile(const PortPlacementProblem& problem, const std::string& path);

/// The largest distance from the skin a ports file's point may have (m).
constexpr double kPortPointSkinTolerance = 0.02;
/// The largest distance from the middle of a space a ports file's point may have (m): half a
/// space and more (spaces are 15-20 mm wide at the front), not a neighbouring space's middle.
constexpr double kPortPointSpaceTolerance = 0.025;

}  // namespace trocar::planners
