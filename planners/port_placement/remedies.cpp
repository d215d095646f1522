#include "port_placement/remedies.hpp"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <optional>
#include <sstream>
#include <tuple>

#include "patient/patient_model.hpp"
#include "port_placement/optimizer.hpp"

namespace trocar::planners {

namespace {

// "ICS-L4" -> 4; 0 for a curve that is not a numbered space.
int SpaceNumber(const std::string& name) {
  if (name.size() < 6 || name.compare(0, 4, "ICS-") != 0) return 0;
  std::size_t used = 0;
  try {
    const int n = std::stoi(name.substr(5), &used);
    return used == name.size() - 5 && n > 0 ? n : 0;
  } catch (const std::exception&) {
    return 0;
  }
}

// Position (0..1 of its arc length) of the point of a candidate curve nearest p_P, and the
// distance to it.
std::pair<double, double> NearestOnCurve(const patient::Curve& curve, const Eigen::Vector3d& p_P) {
  if (curve.size() < 2) return {0.0, curve.empty() ? HUGE_VAL : (curve[0] - p_P).norm()};
  std::vector<double> arc(curve.size(), 0.0);
  for (std::size_t i = 1; i < curve.size(); ++i)
    arc[i] = arc[i - 1] + (curve[i] - curve[i - 1]).norm();
  double best = HUGE_VAL, best_arc = 0.0;
  for (std::size_t i = 0; i + 1 < curve.size(); ++i) {
    const Eigen::Vector3d d = curve[i + 1] - curve[i];
    const double len2 = d.squaredNorm();
    const double f = len2 > 0 ? std::clamp((p_P - curve[i]).dot(d) / len2, 0.0, 1.0) : 0.0;
    const double dist = (curve[i] + f * d - p_P).norm();
    if (dist < best) {
      best = dist;
      best_arc = arc[i] + f * (arc[i + 1] - arc[i]);
    }
  }
  return {arc.back() > 0 ? best_arc / arc.back() : 0.0, best};
}

double CurveLength(const patient::Curve& curve) {
  double l = 0.0;
  for (std::size_t i = 1; i < curve.size(); ++i) l += (curve[i] - curve[i - 1]).norm();
  return l;
}

struct Candidate {
  Remedy::Kind kind;
  Placement placement;
  std::string move;  // "one space higher (ICS-L4)", "20 cm toward the head"
};

int ServedCount(const Evaluation& e, const std::vector<int>& except) {
  int n = 0;
  for (std::size_t s = 0; s < e.served.size(); ++s) {
    if (e.served[s] && std::find(except.begin(), except.end(), static_cast<int>(s)) == except.end())
      ++n;
  }
  return n;
}

}  // namespace

std::string DescribePortMove(const PortPlacementProblem& problem, const PortSite& from,
                             const PortSite& to) {
  const auto& candidates = problem.patient().port_candidates;
  const std::string& name_to = candidates.at(to.candidate).name;
  std::ostringstream s;
  if (to.candidate == from.candidate) {
    // Along its own space: forward is anterior (-y in the patient's LPS frame).
    const double d = (to.p_curve_P - from.p_curve_P).norm();
    s << std::lround(d * 1e3) << " mm further "
      << (to.p_curve_P.y() < from.p_curve_P.y() ? "forward" : "back") << " along " << name_to;
    return s.str();
  }
  const int n_from = SpaceNumber(candidates.at(from.candidate).name), n_to = SpaceNumber(name_to);
  if (n_from > 0 && n_to > 0 && std::abs(n_to - n_from) == 1) {
    s << "one space " << (n_to < n_from ? "higher" : "lower") << " (" << name_to << ")";
  } else if (n_from > 0 && n_to > 0 && n_to != n_from) {
    s << std::abs(n_to - n_from) << " spaces " << (n_to < n_from ? "higher" : "lower") << " ("
      << name_to << ")";
  } else {
    // Unnumbered curves: by the patient's superior axis (+z in LPS).
    s << "on " << name_to << " (" << (to.p_curve_P.z() > from.p_curve_P.z() ? "higher" : "lower")
      << ")";
  }
  return s.str();
}

Remedy FindRemedy(const PortPlacementProblem& problem, const Placement& placement,
                  const Evaluation& evaluation, int arm, const std::vector<int>& stretch,
                  int threads) {
  Remedy none;
  none.arm = arm;
  none.of = static_cast<int>(stretch.size());
  if (arm < 0 || arm >= static_cast<int>(problem.arms().size()) || stretch.empty() ||
      evaluation.status != PlacementStatus::kPlaced) {
    return none;
  }
  const auto& candidates = problem.patient().port_candidates;
  const PortSite& here = placement.sites.at(arm);

  // The changes tried, in the order ties are broken.
  std::vector<Candidate> tried;
  {
    // The nearest other curve above and below where the port is (one space higher and lower).
    std::optional<std::pair<double, int>> above, below;  // distance, candidate
    std::vector<double> s_on(candidates.size(), 0.0);
    for (int c = 0; c < static_cast<int>(candidates.size()); ++c) {
      if (c == here.candidate) continue;
      const auto [s, d] = NearestOnCurve(candidates[c].skin, here.p_curve_P);
      s_on[c] = s;
      const PortSite site = problem.Site(c, s);
      auto& slot = site.p_curve_P.z() > here.p_curve_P.z() ? above : below;
      if (!slot || d < slot->first) slot = std::make_pair(d, c);
    }
    for (const auto& slot : {above, below}) {
      if (!slot) continue;
      Candidate k{Remedy::Kind::kPort, placement, ""};
      k.placement.sites[arm] = problem.Site(slot->second, s_on[slot->second]);
      // Two arms in one place is no remedy.
      bool clash = false;
      for (std::size_t a = 0; a < placement.sites.size(); ++a) {
        if (static_cast<int>(a) != arm &&
            (placement.sites[a].p_W - k.placement.sites[arm].p_W).norm() < 0.03)
          clash = true;
      }
      if (clash) continue;
      k.move = DescribePortMove(problem, here, k.placement.sites[arm]);
      tried.push_back(std::move(k));
    }
    const double length = CurveLength(candidates.at(here.candidate).skin);
    if (length > 0.0) {
      for (double d : {-0.03, 0.03}) {
        const double s = here.s + d / length;
        if (s < 0.0 || s > 1.0) continue;
        Candidate k{Remedy::Kind::kPort, placement, ""};
        k.placement.sites[arm] = problem.Site(here.candidate, s);
        k.move = DescribePortMove(problem, here, k.placement.sites[arm]);
        tried.push_back(std::move(k));
      }
    }
    // The cart: along the table (x_W is toward the head) and toward or away from it (|y_W|).
    for (double dx : {0.1, -0.1, 0.2, -0.2}) {
      Candidate k{Remedy::Kind::kCart, placement, ""};
      k.placement.cart_x += dx;
      std::ostringstream m;
      m << "the cart " << std::lround(std::abs(dx) * 100) << " cm toward the "
        << (dx > 0 ? "head" : "feet");
      k.move = m.str();
      tried.push_back(std::move(k));
    }
    const double side = placement.cart_y < 0 ? -1.0 : 1.0;
    for (double dr : {-0.1, 0.1}) {
      Candidate k{Remedy::Kind::kCart, placement, ""};
      k.placement.cart_y += side * dr;
      std::ostringstream m;
      m << "the cart " << std::lround(std::abs(dr) * 100) << " cm "
        << (dr < 0 ? "closer to" : "further from") << " the table";
      k.move = m.str();
      tried.push_back(std::move(k));
    }
  }

  const bool endoscope = problem.arms()[arm].role == ArmRole::kEndoscope;
  const int served_before = ServedCount(evaluation, {});
  const int kept_before = ServedCount(evaluation, stretch);
  std::vector<Remedy> found(tried.size());
  const int n = static_cast<int>(tried.size());
#pragma omp parallel num_threads(std::max(1, threads))
  {
    std::unique_ptr<Workspace> ws;
#pragma omp for schedule(dynamic, 1)
    for (int i = 0; i < n; ++i) {
      if (!ws) ws = std::make_unique<Workspace>(problem);
      // Exactly as a final plan is evaluated (EvaluateFinalPlan: detailed, the better of the
      // setup-joint solver's search effort and its full effort). Until stop 62 the full effort
      // alone, which lands the setup arms on other solutions than the plan's own.
      const Evaluation e = EvaluateFinalPlan(problem, tried[i].placement, ws.get());
      Remedy& r = found[i];
      r.kind = tried[i].kind;
      r.arm = arm;
      r.placement = tried[i].placement;
      r.of = static_cast<int>(stretch.size());
      r.served_before = served_before;
      if (e.status != PlacementStatus::kPlaced) continue;
      for (const auto& reach : e.reaches) {
        if (reach.arm != arm) continue;
        if (std::find(stretch.begin(), stretch.end(), reach.sample) == stretch.end()) continue;
        if (endoscope ? reach.seen : reach.reached) ++r.reached;
      }
      r.served = ServedCount(e, {});
      r.keeps = ServedCount(e, stretch) >= kept_before;
    }
  }
  int best = -1;
  for (int i = 0; i < n; ++i) {
    if (found[i].reached == 0) continue;
    const auto key = [&](const Remedy& r) { return std::make_tuple(r.keeps, r.reached, r.served); };
    if (best < 0 || key(found[i]) > key(found[best])) best = i;
  }
  if (best < 0) return none;
  Remedy r = found[best];
  std::ostringstream t;
  const std::string& name = problem.arms()[arm].name;
  const std::string verb = endoscope ? "sees" : "reaches";
  if (r.kind == Remedy::Kind::kPort)
    t << name << "'s port " << tried[best].move << " " << verb << " ";
  else
    t << tried[best].move << " lets " << name << (endoscope ? " see " : " reach ");
  if (r.of == 1)
    t << "it";
  else if (r.reached == r.of)
    t << (r.of == 2 ? "both samples" : "all " + std::to_string(r.of) + " samples");
  else
    t << r.reached << " of these " << r.of << " samples";
  t << " (the plan would serve " << r.served << " of " << evaluation.served.size()
    << " samples, now " << served_before;
  if (!r.keeps) t << ", losing some served elsewhere";
  t << ")";
  r.text = t.str();
  return r;
}

}  // namespace trocar::planners
