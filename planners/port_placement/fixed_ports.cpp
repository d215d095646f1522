#include "port_placement/fixed_ports.hpp"

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <limits>
#include <sstream>
#include <string>
#include <utility>

#include "collision/triangle_bvh.hpp"
#include "common/error.hpp"
#include "common/geometry.hpp"
#include "patient/markups.hpp"
#include "patient/patient_model.hpp"

namespace trocar::planners {
namespace {

double Midline(const patient::PatientModel& patient) {
  if (const patient::Structure* s = patient.Find("sternum"); s && !s->mesh.vertices.empty()) {
    double x = 0.0;
    for (const auto& v : s->mesh.vertices) x += v.x();
    return x / static_cast<double>(s->mesh.vertices.size());
  }
  return 0.5 * (patient.body_min_P.x() + patient.body_max_P.x());
}

std::string Mm(double m) {
  std::ostringstream s;
  s << std::lround(m * 1e3) << " mm";
  return s.str();
}

// The point of a candidate curve whose lateral offset from the midline is `offset`: its position
// s (0..1 of the arc length); the crossing nearest the front when the curve crosses that offset
// more than once; else the end nearest it, `miss` set to how far off that end is (m).
double CrossingOnCurve(const patient::Curve& curve, int side, double midline_x, double offset,
                       double* miss) {
  std::vector<double> arc(curve.size(), 0.0);
  for (std::size_t i = 1; i < curve.size(); ++i)
    arc[i] = arc[i - 1] + (curve[i] - curve[i - 1]).norm();
  const double total = arc.back();
  auto lateral = [&](const Eigen::Vector3d& p) { return (p.x() - midline_x) * side; };
  double best_s = -1.0, best_y = std::numeric_limits<double>::infinity();
  for (std::size_t i = 1; i < curve.size(); ++i) {
    const double a = lateral(curve[i - 1]) - offset, b = lateral(curve[i]) - offset;
    if ((a > 0) == (b > 0) && a != 0.0) continue;
    const double f = a == b ? 0.0 : a / (a - b);
    const Eigen::Vector3d p = curve[i - 1] + f * (curve[i] - curve[i - 1]);
    if (p.y() < best_y) {  // LPS: the front is -y
      best_y = p.y();
      best_s = total > 0 ? (arc[i - 1] + f * (arc[i] - arc[i - 1])) / total : 0.0;
    }
  }
  *miss = 0.0;
  if (best_s >= 0.0) return best_s;
  const double first = std::abs(lateral(curve.front()) - offset),
               last = std::abs(lateral(curve.back()) - offset);
  *miss = std::min(first, last);
  return first <= last ? 0.0 : 1.0;
}

// The problem's arms of a role, in order.
std::vector<int> ArmsOfRole(const PortPlacementProblem& problem, ArmRole role) {
  std::vector<int> out;
  for (std::size_t a = 0; a < problem.arms().size(); ++a)
    if (problem.arms()[a].role == role) out.push_back(static_cast<int>(a));
  return out;
}

std::string ArmList(const PortPlacementProblem& problem) {
  std::string s;
  for (const auto& a : problem.arms())
    s += (s.empty() ? "" : ", ") + a.name + " (" + ToString(a.role) + ")";
  return s;
}

}  // namespace

ChestLines ChestLinesAt(const patient::PatientModel& patient, int side, double z_P) {
  const patient::Structure* skin = patient.Find("skin");
  TROCAR_THROW_UNLESS(skin && !skin->mesh.triangles.empty(),
                      "chest lines: patient '" << patient.name << "' has no skin surface");
  ChestLines lines;
  lines.side = side;
  lines.z_P = z_P;
  lines.midline_x = Midline(patient);
  const double centre_y = 0.5 * (patient.body_min_P.y() + patient.body_max_P.y());
  // The ribs' lateral reach at this level, to keep an arm beside the chest out of the lines.
  double rib_reach = std::numeric_limits<double>::infinity();
  if (const patient::Structure* ribs = patient.Find("ribs"); ribs && !ribs->mesh.vertices.empty()) {
    double reach = -1.0;
    for (const auto& v : ribs->mesh.vertices) {
      if (std::abs(v.z() - z_P) <= 0.02) reach = std::max(reach, (v.x() - lines.midline_x) * side);
    }
    if (reach > 0.0) rib_reach = reach;
  }
  if (const patient::Structure* sternum = patient.Find("sternum")) {
    double edge = -1.0;
    int near = 0;
    for (const auto& v : sternum->mesh.vertices) {
      if (std::abs(v.z() - z_P) > 0.015) continue;
      ++near;
      edge = std::max(edge, (v.x() - lines.midline_x) * side);
    }
    if (near >= 3 && edge > 0.0) lines.sternal_edge = edge;
  }
  const auto& mesh = skin->mesh;
  for (const double band : {0.01, 0.02, 0.04}) {
    std::vector<double> lateral_face, turning;
    double mal = -1.0;
    for (const auto& t : mesh.triangles) {
      const Eigen::Vector3d& a = mesh.vertices[t[0]];
      const Eigen::Vector3d& b = mesh.vertices[t[1]];
      const Eigen::Vector3d& c = mesh.vertices[t[2]];
      const Eigen::Vector3d centre = (a + b + c) / 3.0;
      if (std::abs(centre.z() - z_P) > band) continue;
      const double offset = (centre.x() - lines.midline_x) * side;
      if (offset <= 0.0) continue;
      Eigen::Vector3d n = (b - a).cross(c - a);
      const Eigen::Vector2d in_plane(n.x(), n.y());
      if (in_plane.norm() < 0.7 * n.norm() || in_plane.norm() <= 0.0) continue;  // facing up/down
      Eigen::Vector2d d = in_plane.normalized();
      // Outward: away from the body's axis.
      if (d.dot(Eigen::Vector2d(centre.x() - lines.midline_x, centre.y() - centre_y)) < 0) d = -d;
      const double angle = std::atan2(d.x() * side, -d.y()) * 180.0 / M_PI;  // 0 front, 90 side
      if (offset > rib_reach + 0.08) continue;  // an arm beside the chest
      if (angle >= 60.0 && angle <= 120.0) mal = std::max(mal, offset);
      if (angle >= 35.0 && angle <= 55.0) turning.push_back(offset);
    }
    if (mal <= 0.0 || turning.empty()) continue;
    lines.mal = mal;
    std::vector<double> front;  // the turn in front of the side (not the back's)
    for (double o : turning)
      if (o <= mal) front.push_back(o);
    lines.aal = front.empty() ? Median(turning) : Median(front);
    lines.mcl = 0.5 * mal;
    if (lines.aal <= lines.mcl) lines.aal = 0.5 * (lines.mcl + lines.mal);  // a flat, wide chest
    return lines;
  }
  TROCAR_THROW("chest lines: the skin of patient '"
               << patient.name << "' has no lateral face on the " << (side > 0 ? "left" : "right")
               << " at z = " << std::lround(z_P * 1e3) << " mm (outside the scan?)");
}

std::string DescribePort(const patient::PatientModel& patient, const PortSite& site) {
  const std::string& space = patient.port_candidates.at(site.candidate).name;
  const double midline = Midline(patient);
  const int side = site.p_P.x() >= midline ? 1 : -1;
  ChestLines lines;
  try {
    lines = ChestLinesAt(patient, side, site.p_curve_P.z());
  } catch (const Error&) {
    return space;
  }
  const double offset = (site.p_P.x() - lines.midline_x) * side;
  const std::pair<const char*, double> named[] = {{"midclavicular line", lines.mcl},
                                                  {"anterior axillary line", lines.aal},
                                                  {"mid-axillary line", lines.mal}};
  const auto* nearest = &named[0];
  for (const auto& n : named)
    if (std::abs(offset - n.second) < std::abs(offset - nearest->second)) nearest = &n;
  std::ostringstream s;
  s << space << ", ";
  const double d = offset - nearest->second;
  if (std::abs(d) < 0.005)
    s << "on the " << nearest->first;
  else
    s << Mm(std::abs(d)) << (d > 0 ? " lateral" : " medial") << " of the " << nearest->first;
  s << " (" << Mm(offset) << " from the midline";
  if (std::isfinite(lines.sternal_edge))
    s << ", " << Mm(offset - lines.sternal_edge) << " from the sternal edge";
  s << ")";
  return s.str();
}

int SpaceAtLevel(const patient::PatientModel& patient, const Eigen::Vector3d& p_P) {
  int best = 0;
  double nearest = std::numeric_limits<double>::infinity();
  for (const auto& c : patient.port_candidates) {
    // "ICS-L3" / "ICS-R3": the number after the side letter.
    if (c.name.size() < 6 || c.name.compare(0, 4, "ICS-") != 0) continue;
    int number = 0;
    std::size_t used = 0;
    try {
      number = std::stoi(c.name.substr(5), &used);
    } catch (const std::exception&) {
      continue;
    }
    if (used != c.name.size() - 5 || number < 1) continue;
    for (const auto& q : c.skin) {
      const double d = (q - p_P).norm();
      if (d < nearest) {
        nearest = d;
        best = number;
      }
    }
  }
  return best;
}

std::string SpacesText(int first, int last) {
  if (first <= 0 || last <= 0) return "";
  auto ordinal = [](int n) {
    const int t = n % 100;
    const char* suffix = (t >= 11 && t <= 13) ? "th"
                         : n % 10 == 1        ? "st"
                         : n % 10 == 2        ? "nd"
                         : n % 10 == 3        ? "rd"
                                              : "th";
    return std::to_string(n) + suffix;
  };
  if (first > last) std::swap(first, last);
  if (first == last) return ordinal(first) + " intercostal space";
  return ordinal(first) + " to " + ordinal(last) + " intercostal spaces";
}

std::string SpacesAtLevel(const patient::PatientModel& patient,
                          const std::vector<Eigen::Vector3d>& p_W) {
  const Eigen::Isometry3d X_PW = patient.X_WP.inverse();
  int lo = 0, hi = 0;
  for (const Eigen::Vector3d& p : p_W) {
    const int n = SpaceAtLevel(patient, X_PW * p);
    if (n <= 0) continue;
    lo = lo == 0 ? n : std::min(lo, n);
    hi = std::max(hi, n);
  }
  return SpacesText(lo, hi);
}

PortTemplate TecabTemplate() {
  PortTemplate t;
  t.name = "tecab";
  t.title = "robotic TECAB template (Bonatti et al.)";
  t.source =
      "Bonatti, Hasan, Prud'Homme, Mick: Robotic CABG. In Sellke (ed.), Atlas of Cardiac "
      "Surgical Techniques, ch. 7 (camera 5th ICS anterior axillary line; instruments 3rd and 7th "
      "ICS midway between the anterior axillary and midclavicular lines); the same spaces for "
      "robotic LITA harvest, Kiaii et al., ibid. ch. 6";
  t.side = 1;
  t.ports = {{ArmRole::kEndoscope, 5, 1.0, "5th intercostal space, anterior axillary line"},
             {ArmRole::kInstrument, 3, 0.5,
              "3rd intercostal space, midway between the anterior axillary and midclavicular lines"},
             {ArmRole::kInstrument, 7, 0.5,
              "7th intercostal space, midway between the anterior axillary and midclavicular lines"}};
  return t;
}

std::vector<FixedPorts> PlaceTemplate(const PortPlacementProblem& problem,
                                      const PortTemplate& port_template) {
  const patient::PatientModel& patient = problem.patient();
  const std::string side = port_template.side > 0 ? "L" : "R";
  const std::vector<int> instruments = ArmsOfRole(problem, ArmRole::kInstrument);
  const std::vector<int> scopes = ArmsOfRole(problem, ArmRole::kEndoscope);
  std::vector<const TemplatePort*> t_instruments, t_scopes;
  for (const auto& p : port_template.ports)
    (p.role == ArmRole::kInstrument ? t_instruments : t_scopes).push_back(&p);
  // A plan without an endoscope arm (two instruments) takes the template's instrument ports
  // alone; otherwise the arms must match the template's ports role by role.
  TROCAR_THROW_UNLESS(instruments.size() == t_instruments.size() &&
                          (scopes.empty() || scopes.size() == t_scopes.size()),
                      "the " << port_template.title << " has " << t_scopes.size()
                             << " endoscope and " << t_instruments.size()
                             << " instrument ports; the plan's arms are " << ArmList(problem));
  // Each template port on its named space.
  auto place = [&](const TemplatePort& p, std::string* where, std::vector<std::string>* notes) {
    const std::string name = "ICS-" + side + std::to_string(p.space);
    int candidate = -1;
    for (std::size_t c = 0; c < patient.port_candidates.size(); ++c)
      if (patient.port_candidates[c].name == name) candidate = static_cast<int>(c);
    if (candidate < 0) {
      std::string found;
      bool unnumbered = false;
      for (const auto& c : patient.port_candidates) {
        found += (found.empty() ? "" : ", ") + c.name;
        unnumbered = unnumbered || c.name.rfind("gap-", 0) == 0;
      }
      std::ostringstream m;
      m << "the " << port_template.title << " needs " << name << " (the " << p.where
        << "), which patient '" << patient.name << "' does not have; its spaces: "
        << (found.empty() ? "none" : found);
      if (unnumbered)
        m << ". The ribs are not numbered (rib 1 not found): to place the template by the spaces "
             "found in order, say which space the highest one is in the case file "
             "(intercostal: {count_from: N})";
      TROCAR_THROW(m.str());
    }
    const patient::Curve& curve = patient.port_candidates[candidate].skin;
    TROCAR_THROW_UNLESS(curve.size() >= 2, name << ": the space's curve has fewer than 2 points");
    // The lines at the space's level, then again at the level where the port lands.
    double z = 0.0;
    for (const auto& q : curve) z += q.z();
    z /= static_cast<double>(curve.size());
    double s = 0.5, miss = 0.0;
    ChestLines lines;
    for (int pass = 0; pass < 2; ++pass) {
      lines = ChestLinesAt(patient, port_template.side, z);
      const double offset = lines.mcl + p.between_mcl_aal * (lines.aal - lines.mcl);
      s = CrossingOnCurve(curve, port_template.side, lines.midline_x, offset, &miss);
      z = problem.Site(candidate, s).p_curve_P.z();
    }
    std::ostringstream w;
    w << name << " (" << p.where << ")";
    *where = w.str();
    if (miss > 0.005) {
      std::ostringstream n;
      n << name << " ends " << Mm(miss) << " short of the line it is to be placed on (MCL "
        << Mm(lines.mcl) << ", AAL " << Mm(lines.aal) << " from the midline): its nearest end taken";
      notes->push_back(n.str());
    }
    return problem.Site(candidate, s);
  };
  FixedPorts base;
  base.kind = "template";
  base.name = port_template.title;
  base.source = port_template.source;
  base.sites.resize(problem.arms().size());
  base.where.resize(problem.arms().size());
  for (std::size_t k = 0; k < scopes.size(); ++k)
    base.sites[scopes[k]] = place(*t_scopes[k], &base.where[scopes[k]], &base.notes);
  if (scopes.empty() && !t_scopes.empty())
    base.notes.push_back("no endoscope arm in the plan: the template's camera port is left out");
  std::vector<PortSite> t_sites(t_instruments.size());
  std::vector<std::string> t_where(t_instruments.size());
  for (std::size_t k = 0; k < t_instruments.size(); ++k)
    t_sites[k] = place(*t_instruments[k], &t_where[k], &base.notes);
  // Every assignment of the template's instrument ports to the instrument arms (two arms: as
  // listed, and swapped).
  std::vector<int> order(t_instruments.size());
  for (std::size_t k = 0; k < order.size(); ++k) order[k] = static_cast<int>(k);
  std::vector<FixedPorts> out;
  do {
    FixedPorts v = base;
    for (std::size_t k = 0; k < instruments.size(); ++k) {
      v.sites[instruments[k]] = t_sites[order[k]];
      v.where[instruments[k]] = t_where[order[k]];
    }
    out.push_back(std::move(v));
  } while (std::next_permutation(order.begin(), order.end()));
  return out;
}

FixedPorts ReadPortsFile(const PortPlacementProblem& problem, const std::string& path) {
  const std::vector<patient::Markup> markups = patient::LoadMarkups(path);
  const patient::Markup* list = nullptr;
  int lists = 0;
  for (const auto& m : markups) {
    if (m.type == "Curve" || m.type == "ClosedCurve" || m.type == "Line") continue;
    ++lists;
    if (!list) list = &m;
  }
  TROCAR_THROW_UNLESS(list, path << ": no point list (expected a 3D Slicer point list with one "
                                    "point per arm, labelled with the arm's name)");
  const patient::PatientModel& patient = problem.patient();
  const auto& arms = problem.arms();
  FixedPorts out;
  out.kind = "surgeon";
  out.name = path;
  out.source = "ports file " + path + ", point list '" + list->name + "'";
  if (lists > 1)
    out.notes.push_back(path + " holds " + std::to_string(lists) + " point lists: the first, '" +
                        list->name + "', taken");
  out.sites.resize(arms.size());
  out.where.resize(arms.size());
  std::vector<int> given(arms.size(), -1);
  const patient::Structure* skin = patient.Find("skin");
  std::unique_ptr<collision::TriangleBvh> skin_bvh;
  if (skin && !skin->mesh.triangles.empty())
    skin_bvh = std::make_unique<collision::TriangleBvh>(skin->mesh);
  for (std::size_t i = 0; i < list->points.size(); ++i) {
    const std::string label = i < list->labels.size() ? list->labels[i] : "";
    const Eigen::Vector3d& p = list->points[i];
    std::ostringstream point;
    point << path << ": point " << i + 1 << " '" << label << "' (LPS mm " << std::fixed
          << std::setprecision(0) << p.x() * 1e3 << ", " << p.y() * 1e3 << ", " << p.z() * 1e3
          << ")";
    int arm = -1;
    for (std::size_t a = 0; a < arms.size(); ++a)
      if (!label.empty() && (arms[a].name == label || arms[a].rcm_frame == label))
        arm = static_cast<int>(a);
    TROCAR_THROW_UNLESS(arm >= 0, point.str() << ": its label names no arm of the plan (arms: "
                                              << ArmList(problem)
                                              << "; label each point with its arm's name)");
    TROCAR_THROW_UNLESS(given[arm] < 0, point.str() << ": a second point for arm " << arms[arm].name
                                                    << " (point " << given[arm] + 1
                                                    << " is its port)");
    given[arm] = static_cast<int>(i);
    if (skin_bvh) {
      const auto c = skin_bvh->Closest(p, p);
      const double d = c.found() ? c.distance : std::numeric_limits<double>::infinity();
      TROCAR_THROW_UNLESS(d <= kPortPointSkinTolerance,
                          point.str() << ": " << Mm(d) << " from the patient's skin (at most "
                                      << Mm(kPortPointSkinTolerance)
                                      << "): not a port on this patient (a point list in another "
                                         "patient's frame, or in RAS read as LPS?)");
    }
    // The nearest point of the middle of a space.
    int best_c = -1;
    double best_d = std::numeric_limits<double>::infinity(), best_s = 0.0;
    for (std::size_t c = 0; c < patient.port_candidates.size(); ++c) {
      const patient::Curve& curve = patient.port_candidates[c].skin;
      if (curve.size() < 2) continue;
      double total = 0.0;
      std::vector<double> arc(curve.size(), 0.0);
      for (std::size_t k = 1; k < curve.size(); ++k)
        arc[k] = total += (curve[k] - curve[k - 1]).norm();
      for (std::size_t k = 1; k < curve.size(); ++k) {
        const Eigen::Vector3d e = curve[k] - curve[k - 1];
        const double f =
            e.squaredNorm() > 0 ? std::clamp((p - curve[k - 1]).dot(e) / e.squaredNorm(), 0.0, 1.0) : 0.0;
        const double d = (curve[k - 1] + f * e - p).norm();
        if (d < best_d) {
          best_d = d;
          best_c = static_cast<int>(c);
          best_s = total > 0 ? (arc[k - 1] + f * (arc[k] - arc[k - 1])) / total : 0.0;
        }
      }
    }
    TROCAR_THROW_UNLESS(best_c >= 0 && best_d <= kPortPointSpaceTolerance,
                        point.str() << ": "
                                    << (best_c >= 0 ? Mm(best_d) + " from the middle of the nearest "
                                                                   "intercostal space (" +
                                                          patient.port_candidates[best_c].name + ")"
                                                    : std::string("the patient has no intercostal "
                                                                  "spaces"))
                                    << ", more than " << Mm(kPortPointSpaceTolerance)
                                    << ": ports go between the ribs");
    out.sites[arm] = problem.Site(best_c, best_s);
    std::ostringstream w;
    w << "point '" << label << "', " << Mm(best_d) << " from the middle of "
      << patient.port_candidates[best_c].name;
    out.where[arm] = w.str();
  }
  std::string missing;
  for (std::size_t a = 0; a < arms.size(); ++a)
    if (given[a] < 0) missing += (missing.empty() ? "" : ", ") + arms[a].name;
  TROCAR_THROW_UNLESS(missing.empty(), path << ": point list '" << list->name
                                            << "' has no point for arm " << missing
                                            << " (one point per arm, labelled with its name)");
  return out;
}

}  // namespace trocar::planners
