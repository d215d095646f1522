#include "plan/reachability.hpp"

#include <algorithm>
#include <cmath>
#include <map>
#include <numeric>
#include <sstream>

#include "common/error.hpp"

namespace trocar::planners {
namespace {

// Per arm and sample: whether the arm succeeds there, and why not.
struct Cell {
  bool known = false, ok = false;
  std::string why;
};

}  // namespace

Reachability TargetReachability(const PlanFile& file, const StoredPlan& plan,
                                const LevelText& level) {
  const std::size_t ns = file.samples.size(), na = file.arms.size();
  Reachability r;
  r.verified = plan.verified;
  std::vector<std::vector<Cell>> cells(na, std::vector<Cell>(ns));
  auto arm_index = [&](const std::string& name) {
    for (std::size_t a = 0; a < na; ++a)
      if (file.arms[a].name == name) return a;
    TROCAR_THROW(file.path << ": plan " << plan.rank << " names arm '" << name
                           << "', which the plan file's arms do not list");
  };
  auto check_sample = [&](int s, const char* what) {
    TROCAR_THROW_UNLESS(s >= 0 && static_cast<std::size_t>(s) < ns,
                        file.path << ": plan " << plan.rank << " has a " << what << " at sample "
                                  << s << ", and the file has " << ns << " target samples");
  };
  std::vector<bool> endoscope(na);
  for (std::size_t a = 0; a < na; ++a) endoscope[a] = file.arms[a].role == "endoscope";
  // The claim: every arm's reach (an endoscope's "seen").
  for (const StoredReach& reach : plan.reaches) {
    check_sample(reach.sample, "reach");
    const std::size_t a = arm_index(reach.arm);
    Cell& c = cells[a][reach.sample];
    c.known = true;
    c.ok = reach.endoscope ? reach.seen : reach.reached;
    c.why = reach.reason;
    if (reach.endoscope && !reach.seen && c.why.empty()) c.why = "not seen";
  }
  // The verification replaces the instruments' claims by their verified motions (the endoscope
  // is judged by its view, as the verification does).
  if (plan.verified) {
    for (std::size_t a = 0; a < na; ++a) {
      if (endoscope[a]) continue;
      for (auto& c : cells[a]) c = Cell{};
    }
    for (const StoredMotion& m : plan.motions) {
      check_sample(m.sample, "motion");
      const std::size_t a = arm_index(m.arm);
      Cell& c = cells[a][m.sample];
      c.known = true;
      c.ok = m.solved;
      c.why = m.solved ? "" : (m.reason.empty() ? m.outcome : m.outcome + ": " + m.reason);
    }
  }
  const std::vector<bool>& served = plan.verified ? plan.verified_served : plan.served;
  r.per_sample.assign(ns, ReachClass::kNone);
  bool any_scope = false;
  for (std::size_t a = 0; a < na; ++a) any_scope = any_scope || endoscope[a];
  for (std::size_t s = 0; s < ns; ++s) {
    bool some = false, all = true, seen = !any_scope;
    for (std::size_t a = 0; a < na; ++a) {
      const bool ok = cells[a][s].known && cells[a][s].ok;
      if (endoscope[a]) {
        seen = seen || ok;
      } else {
        some = some || ok;
        all = all && ok;
      }
    }
    const bool is_served = s < served.size() ? static_cast<bool>(served[s]) : (all && seen);
    r.per_sample[s] =
        is_served ? ReachClass::kServed : (some ? ReachClass::kPartly : ReachClass::kNone);
  }
  // The targets in their first sample's order, each's samples along it.
  std::vector<std::string> targets;
  for (const auto& s : file.samples)
    if (std::find(targets.begin(), targets.end(), s.target) == targets.end())
      targets.push_back(s.target);
  for (const std::string& target : targets) {
    std::vector<int> along;
    for (std::size_t s = 0; s < ns; ++s)
      if (file.samples[s].target == target) along.push_back(static_cast<int>(s));
    std::stable_sort(along.begin(), along.end(), [&](int a, int b) {
      return file.samples[a].arc_length < file.samples[b].arc_length;
    });
    auto same = [&](int s, int t) {
      for (std::size_t a = 0; a < na; ++a) {
        const bool x = cells[a][s].known && cells[a][s].ok, y = cells[a][t].known && cells[a][t].ok;
        if (x != y) return false;
      }
      return r.per_sample[s] == r.per_sample[t];
    };
    std::size_t i = 0;
    while (i < along.size()) {
      std::size_t j = i;
      while (j + 1 < along.size() && same(along[i], along[j + 1])) ++j;
      TargetStretch st;
      st.target = target;
      st.samples.assign(along.begin() + i, along.begin() + j + 1);
      st.from_m = file.samples[along[i]].arc_length;
      st.to_m = file.samples[along[j]].arc_length;
      st.length_m = file.samples[along.back()].arc_length;
      st.reach = r.per_sample[along[i]];
      st.served = st.reach == ReachClass::kServed;
      for (std::size_t a = 0; a < na; ++a) {
        ArmOnStretch on;
        on.arm = file.arms[a].name;
        on.endoscope = endoscope[a];
        on.reaches = cells[a][along[i]].known && cells[a][along[i]].ok;
        if (!on.reaches) {
          std::map<std::string, int> count;
          for (int s : st.samples) {
            const Cell& c = cells[a][s];
            ++count[c.known ? (c.why.empty() ? std::string("not reached") : c.why)
                            : std::string(plan.verified && !endoscope[a] ? "no verified motion"
                                                                         : "not checked")];
          }
          on.why_not =
              std::max_element(count.begin(), count.end(), [](const auto& x, const auto& y) {
                return x.second < y.second;
              })->first;
        }
        st.arms.push_back(on);
      }
      if (level) {
        std::vector<Eigen::Vector3d> p_W;
        for (int s : st.samples) p_W.push_back(file.samples[s].p_W);
        st.level = level(p_W);
      }
      r.stretches.push_back(std::move(st));
      i = j + 1;
    }
  }
  return r;
}

Reachability TargetReachability(const PlanFile& file, std::size_t index, const LevelText& level) {
  TROCAR_THROW_UNLESS(index < file.plans.size(), file.path << ": no plan " << index + 1
                                                           << " (the file has " << file.plans.size()
                                                           << ")");
  return TargetReachability(file, file.plans[index], level);
}

std::string AlongTarget(double from_m, double to_m, double length_m) {
  std::ostringstream s;
  const long from = std::lround(from_m * 1e3), to = std::lround(to_m * 1e3);
  if (from == to)
    s << from << " mm from its first point";
  else
    s << from << "–" << to << " mm from its first point";
  if (length_m > 0.0) {
    static const char* kThird[] = {"proximal", "middle", "distal"};
    auto third = [&](double x) { return std::clamp(static_cast<int>(3.0 * x / length_m), 0, 2); };
    const int a = third(from_m), b = third(to_m);
    if (a == 0 && b == 2)
      s << " (its whole length)";
    else if (a == b)
      s << " (its " << kThird[a] << " third)";
    else
      s << " (its " << kThird[a] << " and " << kThird[b] << " thirds)";
  }
  return s.str();
}

std::string StretchText(const TargetStretch& stretch) {
  return AlongTarget(stretch.from_m, stretch.to_m, stretch.length_m);
}

}  // namespace trocar::planners
