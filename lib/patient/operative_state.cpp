#include "patient/operative_state.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "common/mesh.hpp"
#include "patient/patient_model.hpp"

namespace trocar::patient {

std::string OperativeState::Describe() const {
  if (!moves()) return applied ? "operative, nothing moved (no CO2, both lungs ventilated)" : "the CT's state";
  std::ostringstream s;
  s << "operative: CO2 " << co2_mmhg << " mmHg"
    << (left_lung_isolated ? ", left lung isolated" : ", both lungs ventilated") << ", heart "
    << heart_shift * 1e3 << " mm (" << heart_shift_min * 1e3 << "-" << heart_shift_max * 1e3
    << ") along gravity";
  return s.str();
}

bool IsMobileStructure(const std::string& name) {
  for (const char* fixed : {"skin", "rib", "sternum", "cartilage", "spine", "vertebra", "clavicle",
                            "scapula", "humerus"}) {
    if (name.find(fixed) != std::string::npos) return false;
  }
  return true;
}

bool TargetLiesOn(const PatientModel& model, int target, const std::string& structure) {
  constexpr double kOnSurface = 0.01;  // m
  const Structure* s = model.Find(structure);
  if (!s || s->mesh.triangles.empty() || target < 0 ||
      target >= static_cast<int>(model.targets.size()))
    return false;
  const auto& points = model.targets[target].points;
  if (points.empty()) return false;
  std::vector<double> d;
  for (const auto& p : points) d.push_back(DistanceToMesh(s->mesh, p));
  std::nth_element(d.begin(), d.begin() + d.size() / 2, d.end());
  return d[d.size() / 2] < kOnSurface;
}

Eigen::Vector3d GravityInPatient(const PatientModel& model) {
  return (model.X_WP.linear().transpose() * -Eigen::Vector3d::UnitZ()).normalized();
}

OperativeChange MoveMobile(const Eigen::Vector3d& d_P, PatientModel* model) {
  OperativeChange change;
  change.d_P = d_P;
  // Which targets move is decided before anything moves (on the structures' CT positions).
  std::vector<char> moving_target(model->targets.size(), 0);
  for (const auto& s : model->structures) {
    if (!IsMobileStructure(s.name) || s.mesh.triangles.empty()) continue;
    for (std::size_t t = 0; t < model->targets.size(); ++t) {
      if (!moving_target[t] && TargetLiesOn(*model, static_cast<int>(t), s.name))
        moving_target[t] = 1;
    }
  }
  for (auto& s : model->structures) {
    if (!IsMobileStructure(s.name) || s.mesh.vertices.empty()) continue;
    for (auto& v : s.mesh.vertices) v += d_P;
    change.structures.push_back(s.name);
  }
  for (std::size_t t = 0; t < model->targets.size(); ++t) {
    if (!moving_target[t]) continue;
    for (auto& p : model->targets[t].points) p += d_P;
    change.targets.push_back(model->targets[t].name);
  }
  return change;
}

void ApplyOperativeState(const OperativeState& state, PatientModel* model) {
  model->operation = state;
  model->operative_change = OperativeChange{};
  const Eigen::Vector3d g_P = GravityInPatient(*model);
  model->operative_change.direction_P = g_P;
  if (!state.moves()) return;
  model->operative_change = MoveMobile(state.heart_shift * g_P, model);
  model->operative_change.direction_P = g_P;
}

std::vector<Eigen::Vector3d> OperativeRobustnessShifts(const PatientModel& model) {
  const OperativeState& s = model.operation;
  std::vector<Eigen::Vector3d> shifts;
  if (!s.moves() || s.heart_shift_max - s.heart_shift_min <= 0.0) return shifts;
  const Eigen::Vector3d g = model.operative_change.direction_P.norm() > 0.5
                                ? model.operative_change.direction_P
                                : GravityInPatient(model);
  shifts.push_back((s.heart_shift_min - s.heart_shift) * g);
  shifts.push_back((s.heart_shift_max - s.heart_shift) * g);
  // Across the direction: the patient's head-foot axis, and the third axis.
  const Eigen::Vector3d u = (Eigen::Vector3d::UnitZ() - g.dot(Eigen::Vector3d::UnitZ()) * g).normalized();
  const Eigen::Vector3d v = g.cross(u).normalized();
  const double half = 0.5 * (s.heart_shift_max - s.heart_shift_min);
  for (const Eigen::Vector3d& axis : {u, v}) {
    shifts.push_back(half * axis);
    shifts.push_back(-half * axis);
  }
  return shifts;
}

}  // namespace trocar::patient
