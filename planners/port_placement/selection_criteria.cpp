#include "port_placement/selection_criteria.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <sstream>

#include "collision/triangle_bvh.hpp"
#include "common/geometry.hpp"
#include "patient/patient_model.hpp"

namespace trocar::planners {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

const char* kBonatti =
    "Bonatti et al., Robotic CABG, in Sellke (ed.), Atlas of Cardiac Surgical Techniques, ch. 7; "
    "Kiaii et al., ibid. ch. 6 (../shared/reference/port-placement.md)";

// The chest wall, for depths under it: its ribs and sternum, with the intercostal spaces between
// them closed (the muscle there is wall too). A point's depth is measured toward the skin point
// nearest it: the nearest stretch of bone a shaft of `kSpaceBridge` radius along that line meets
// (a space is 15-20 mm wide, so the ribs bounding a space lie within it of the space's middle),
// or the nearest bone if that is nearer. Without a skin, the nearest bone.
struct Wall {
  static constexpr double kSpaceBridge = 0.015;  // m
  std::vector<std::unique_ptr<collision::TriangleBvh>> parts;
  std::vector<Eigen::Vector3d> bone_vertices;
  std::unique_ptr<collision::TriangleBvh> skin;
  double NearestBone(const Eigen::Vector3d& p) const {
    double best = std::numeric_limits<double>::infinity();
    for (const auto& b : parts) {
      const auto c = b->Closest(p, p);
      if (c.found()) best = std::min(best, c.distance);
    }
    return best;
  }
  double Distance(const Eigen::Vector3d& p) const {
    const double nearest = NearestBone(p);
    if (!skin) return nearest;
    const auto out = skin->Closest(p, p);
    if (!out.found() || out.distance < 1e-9) return nearest;
    const Eigen::Vector3d u = (out.p_M_mesh - p) / out.distance;
    double best = std::numeric_limits<double>::infinity();
    for (const Eigen::Vector3d& v : bone_vertices) {
      const Eigen::Vector3d d = v - p;
      const double t = d.dot(u);
      if (t <= 0.0 || t >= best) continue;
      if ((d - t * u).squaredNorm() <= kSpaceBridge * kSpaceBridge) best = t;
    }
    return std::min(nearest, best);
  }
};

// A criterion of the TECAB selection (all from Bonatti's and Kiaii's chapters), not yet measured.
Criterion Published(const char* name, const char* title, const char* unit, double threshold,
                    const char* meaning) {
  Criterion c;
  c.name = name;
  c.title = title;
  c.unit = unit;
  c.threshold = threshold;
  c.meaning = meaning;
  c.source = kBonatti;
  c.value = kNaN;
  return c;
}

const patient::Structure* Find(const patient::PatientModel& m, const char* name) {
  const patient::Structure* s = m.Find(name);
  return s && !s->mesh.triangles.empty() ? s : nullptr;
}

}  // namespace

bool Criterion::measured() const { return std::isfinite(value); }

bool Criterion::favourable() const {
  return measured() && (at_least ? value >= threshold : value <= threshold);
}

int SelectionCriteria::measured() const {
  return static_cast<int>(std::count_if(criteria.begin(), criteria.end(),
                                        [](const Criterion& c) { return c.measured(); }));
}

int SelectionCriteria::against() const {
  return static_cast<int>(std::count_if(criteria.begin(), criteria.end(), [](const Criterion& c) {
    return c.measured() && !c.favourable();
  }));
}

std::string SelectionCriteria::Compare(bool suitable) const {
  const int n = measured(), k = against();
  std::ostringstream s;
  if (n == 0) return "no anatomical criterion could be measured on this model";
  std::string names;
  for (const Criterion& c : criteria)
    if (c.measured() && !c.favourable()) names += (names.empty() ? "" : ", ") + c.title;
  if (suitable && k == 0) {
    s << "agree: all " << n << " measured anatomical criteria favour robotic TECAB";
  } else if (suitable) {
    s << "the planner finds a plan although " << k << " of " << n
      << " anatomical criteria are against robotic TECAB (" << names
      << "): check those stretches closely";
  } else if (k == 0) {
    s << "the anatomy does not support 'not suitable': all " << n
      << " measured criteria favour robotic TECAB, so the cause lies in the robot's setup or "
         "the planner's world model (see the reasons), not in the patient";
  } else {
    s << "agree: " << k << " of " << n << " anatomical criteria are against robotic TECAB ("
      << names << ")";
  }
  return s.str();
}

SelectionCriteria MeasureSelectionCriteria(const patient::PatientModel& m,
                                           const Eigen::Vector3d* camera_pivot_P) {
  SelectionCriteria out;
  const patient::Structure* heart = Find(m, "heart");
  const patient::Structure* ribs = Find(m, "ribs");
  const patient::Structure* sternum = Find(m, "sternum");
  Wall wall;
  if (ribs) wall.parts.push_back(std::make_unique<collision::TriangleBvh>(ribs->mesh));
  if (sternum) wall.parts.push_back(std::make_unique<collision::TriangleBvh>(sternum->mesh));
  for (const patient::Structure* bone : {ribs, sternum})
    if (bone) wall.bone_vertices.insert(wall.bone_vertices.end(), bone->mesh.vertices.begin(),
                                        bone->mesh.vertices.end());
  if (const patient::Structure* skin_for_wall = Find(m, "skin"))
    wall.skin = std::make_unique<collision::TriangleBvh>(skin_for_wall->mesh);
  std::unique_ptr<collision::TriangleBvh> heart_bvh;
  if (heart) heart_bvh = std::make_unique<collision::TriangleBvh>(heart->mesh);
  auto missing = [](const std::vector<std::pair<const char*, const void*>>& need) {
    std::string s;
    for (const auto& [name, p] : need)
      if (!p) s += (s.empty() ? "" : ", ") + std::string(name);
    return s.empty() ? s : "not measured: the model has no " + s;
  };
  Eigen::Vector3d heart_centre = Eigen::Vector3d::Zero();
  if (heart) {
    for (const auto& v : heart->mesh.vertices) heart_centre += v;
    heart_centre /= static_cast<double>(heart->mesh.vertices.size());
  }

  // 1. The left ventricle to the anterior chest wall.
  {
    Criterion c = Published("heart_to_chest_wall", "left ventricle to the chest wall", "mm", 25.0,
                            "under 25 mm: a relative contraindication (no room between the heart "
                            "and the wall)");
    c.how = missing({{"heart", heart}, {"ribs or sternum", wall.parts.empty() ? nullptr : &wall}});
    if (c.how.empty()) {
      c.how =
          "the median distance from the heart's left lateral wall (its vertices within 1 cm of "
          "its leftmost point: the left ventricle's free wall; the model has no separate "
          "ventricle) to the chest wall (ribs and sternum, the intercostal spaces between them "
          "closed), on the CT";
      double leftmost = -HUGE_VAL;
      for (const auto& v : heart->mesh.vertices) leftmost = std::max(leftmost, v.x());  // LPS: left +x
      std::vector<double> d;
      for (const auto& v : heart->mesh.vertices)
        if (v.x() >= leftmost - 0.01) d.push_back(wall.Distance(v));
      const double median = Median(d);
      if (std::isfinite(median)) c.value = median * 1e3;
    }
    out.criteria.push_back(c);
  }
  // 2. The chest's front-back to side-to-side ratio at the heart's level.
  {
    Criterion c = Published("chest_ap_to_transverse", "chest front-back to side-to-side ratio", "%",
                            45.0, "under 45 %: a flat chest, lower success");
    const patient::Structure* skin = Find(m, "skin");
    c.how = missing({{"heart", heart}, {"skin", skin}, {"ribs", ribs}});
    if (c.how.empty()) {
      // The chest's outer diameters at the heart's level (the ratio a surgeon sees; the bony
      // thorax's inner ratio is about 40 % in normal adults, Haller index 2.5, and would call
      // most patients flat). Arms beside the chest are left out: skin more than 8 cm outside
      // the rib cage's side.
      const double z = heart_centre.z(), band = 0.01;
      double rib_left = -HUGE_VAL, rib_right = HUGE_VAL;
      for (const auto& v : ribs->mesh.vertices) {
        if (std::abs(v.z() - z) > 2 * band) continue;
        rib_left = std::max(rib_left, v.x());
        rib_right = std::min(rib_right, v.x());
      }
      double left = -HUGE_VAL, right = HUGE_VAL, front = HUGE_VAL, back = -HUGE_VAL;
      if (rib_left > rib_right) {
        for (const auto& v : skin->mesh.vertices) {
          if (std::abs(v.z() - z) > band || v.x() > rib_left + 0.08 || v.x() < rib_right - 0.08)
            continue;
          left = std::max(left, v.x());
          right = std::min(right, v.x());
          front = std::min(front, v.y());  // LPS: the front is -y
          back = std::max(back, v.y());
        }
      }
      c.how =
          "on the CT's skin at the heart's level: front to back over side to side (arms beside "
          "the chest left out)";
      if (left > right && back > front)
        c.value = 100.0 * (back - front) / (left - right);
      else
        c.how = "not measured: the skin or the ribs do not reach the heart's level";
    }
    out.criteria.push_back(c);
  }
  // 3. The LAD's depth under the chest wall.
  {
    Criterion c = Published("lad_to_chest_wall", "LAD to the chest wall", "mm", 15.0,
                            "under 15 mm: lower chance of a totally endoscopic graft");
    const patient::Target* lad = nullptr;
    for (const auto& t : m.targets)
      if (t.name == "LAD") lad = &t;
    c.how = missing({{"LAD target", lad}, {"ribs or sternum", wall.parts.empty() ? nullptr : &wall}});
    if (c.how.empty()) {
      std::vector<double> d;
      for (const auto& p : lad->points) d.push_back(wall.Distance(p));
      c.value = Median(d) * 1e3;
      c.how =
          "the median over the LAD's points of their distance to the chest wall (ribs and sternum, "
          "the intercostal spaces between them closed), on the CT";
    }
    out.criteria.push_back(c);
  }
  // 4. At the camera port: from the chest wall to the mediastinum.
  {
    Criterion c = Published("camera_port_to_mediastinum", "pleura to mediastinum at the camera port",
                            "mm", 17.0, "at least 17 mm for the endoscope to enter");
    c.how = !camera_pivot_P ? std::string("not measured: no endoscope arm in the plan")
                            : missing({{"heart", heart}});
    if (c.how.empty()) {
      const auto hit = heart_bvh->Closest(*camera_pivot_P, *camera_pivot_P);
      if (hit.found()) c.value = hit.distance * 1e3;
      c.how =
          "from the camera port's pivot (in the chest wall, at the pleura) to the heart (the "
          "mediastinum's front), on the CT";
    }
    out.criteria.push_back(c);
  }
  return out;
}

}  // namespace trocar::planners
