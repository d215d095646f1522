// What would serve a stretch the plan leaves unserved (port_placement/remedies.hpp; issue #43
// item 4): every remedy said is a placement that, evaluated on its own, does what the words say.
#include "port_placement/remedies.hpp"

#include <gtest/gtest.h>

#include <set>

#include "patient/patient_model.hpp"
#include "planners/bundled.hpp"
#include "port_placement/fixed_ports.hpp"
#include "port_placement/optimizer.hpp"

namespace trocar::planners {
namespace {

using test_bundled::Cart;
using test_bundled::Phantom;

bool SameSite(const PortSite& a, const PortSite& b) {
  return a.candidate == b.candidate && a.s == b.s && (a.p_W - b.p_W).norm() < 1e-12;
}

// On the bundled phantom, the surgeons' template, the plans of a short search, and the best of
// them with one instrument's port moved a space up or down leave some of each instrument's
// samples unreached. For each instrument of each of those plans, the remedy for the samples it
// misses is checked against an independent evaluation of the placement it names: the arm reaches
// exactly the count said, the plan serves the count said, only the named port (or only the cart)
// moved, and the words name the curve it moved to and the direction it moved in (higher is
// toward the head, +z of LPS). The same call on one thread and on two says the same. A remedy
// that counted the wrong arm, an evaluation other than the plan's, or a move it did not make, or
// called a lower space higher, fails here; and at least one remedy is found (a search that never
// finds one fails too).
TEST(Remedies, EachRemedyIsAPlacementThatDoesWhatItsWordsSay) {
  const PortPlacementProblem problem(Phantom(), Cart(), {});
  PortPlacementOptions o;
  o.threads = 2;
  o.polish_evaluations = 20;
  o.robustness_shift = 0.0;
  o.remedies = true;
  const FixedPortsPlan plan = PlanFixedPorts(problem, PlaceTemplate(problem, TecabTemplate()), o);
  ASSERT_EQ(plan.plan.evaluation.status, PlacementStatus::kPlaced);
  // The verdict, with remedies on, ends every stretch's line with what would reach it or that
  // nothing tried does.
  ASSERT_FALSE(plan.verdict.suitable);
  ASSERT_FALSE(plan.verdict.reasons.empty());
  for (const std::string& line : plan.verdict.reasons) {
    const bool remedy = line.find("(the plan would serve ") != std::string::npos;
    const bool none = line.find("no port one space up or down") != std::string::npos;
    EXPECT_TRUE(remedy != none) << line;
  }
  std::vector<std::pair<Placement, Evaluation>> plans{{plan.plan.placement, plan.plan.evaluation}};
  PortPlacementOptions search;
  search.threads = 2;
  search.evaluations = 300;
  search.polish_evaluations = 8;
  search.top_k = 2;
  search.robustness_shift = 0.0;
  search.time_limit = 600;  // the budget ends the run, not the clock
  for (const auto& p : OptimizePorts(problem, search).plans)
    if (p.evaluation.status == PlacementStatus::kPlaced)
      plans.emplace_back(p.placement, p.evaluation);
  const auto& candidates = problem.patient().port_candidates;
  // And the best searched plan with one instrument's port moved a space up or down: what it
  // reached from its own space, a remedy can give back.
  if (plans.size() > 1) {
    Workspace ws(problem);
    const Placement best = plans[1].first;
    for (int arm = 0; arm < static_cast<int>(problem.arms().size()); ++arm) {
      if (problem.arms()[arm].role != ArmRole::kInstrument) continue;
      for (int step : {-1, 1}) {
        const int c = best.sites[arm].candidate + step;
        if (c < 0 || c >= static_cast<int>(candidates.size())) continue;
        Placement moved = best;
        moved.sites[arm] = problem.Site(c, best.sites[arm].s);
        const Evaluation e = EvaluateFinalPlan(problem, moved, &ws);
        if (e.status == PlacementStatus::kPlaced) plans.emplace_back(moved, e);
      }
    }
  }
  int found = 0;
  for (std::size_t k = 0; k < plans.size(); ++k) {
    const auto& [placement, evaluation] = plans[k];
    SCOPED_TRACE(k == 0 ? std::string("the template") : "searched plan " + std::to_string(k));
    for (int arm = 0; arm < static_cast<int>(problem.arms().size()); ++arm) {
      if (problem.arms()[arm].role != ArmRole::kInstrument) continue;
      std::vector<int> missed;
      for (const auto& r : evaluation.reaches)
        if (r.arm == arm && !r.reached) missed.push_back(r.sample);
      if (missed.empty()) continue;
      const Remedy one = FindRemedy(problem, placement, evaluation, arm, missed, 1);
      const Remedy two = FindRemedy(problem, placement, evaluation, arm, missed, 2);
      EXPECT_EQ(one.text, two.text);
      EXPECT_EQ(one.reached, two.reached);
      EXPECT_EQ(one.of, static_cast<int>(missed.size()));
      if (one.reached == 0) {
        EXPECT_TRUE(one.text.empty());
        continue;
      }
      ++found;
      const std::string& name = problem.arms()[arm].name;
      SCOPED_TRACE(one.text);
      EXPECT_NE(one.text.find(name), std::string::npos);
      // Independently: the named placement, evaluated as a final plan is (the better of the two
      // setup-joint efforts, each evaluated here).
      Workspace ws(problem);
      PortPlacementProblem::EvaluateOptions how;
      how.detailed = true;
      const Evaluation searched = problem.Evaluate(one.placement, &ws, how);
      how.full_solver = true;
      const Evaluation full = problem.Evaluate(one.placement, &ws, how);
      const Evaluation& e = full.score > searched.score ? full : searched;
      ASSERT_EQ(e.status, PlacementStatus::kPlaced);
      const std::set<int> stretch(missed.begin(), missed.end());
      int reached = 0;
      for (const auto& r : e.reaches)
        if (r.arm == arm && r.reached && stretch.count(r.sample)) ++reached;
      EXPECT_EQ(reached, one.reached);
      int served = 0, served_before = 0;
      for (bool s : e.served) served += s;
      for (bool s : evaluation.served) served_before += s;
      EXPECT_EQ(served, one.served);
      EXPECT_EQ(served_before, one.served_before);
      EXPECT_NE(one.text.find("serve " + std::to_string(served) + " of"), std::string::npos);
      // Only what the words say moved.
      if (one.kind == Remedy::Kind::kPort) {
        EXPECT_EQ(one.placement.cart_x, placement.cart_x);
        EXPECT_EQ(one.placement.cart_y, placement.cart_y);
        EXPECT_EQ(one.placement.cart_yaw, placement.cart_yaw);
        for (int a = 0; a < static_cast<int>(placement.sites.size()); ++a) {
          EXPECT_EQ(SameSite(one.placement.sites[a], placement.sites[a]), a != arm) << "arm " << a;
        }
        const PortSite& from = placement.sites[arm];
        const PortSite& to = one.placement.sites[arm];
        EXPECT_NE(one.text.find(candidates[to.candidate].name), std::string::npos);
        if (to.candidate != from.candidate) {
          const bool higher = to.p_curve_P.z() > from.p_curve_P.z();
          EXPECT_NE(one.text.find(higher ? "higher" : "lower"), std::string::npos);
        } else {
          EXPECT_NEAR((to.p_curve_P - from.p_curve_P).norm(), 0.03, 0.005);
        }
      } else {
        for (int a = 0; a < static_cast<int>(placement.sites.size()); ++a)
          EXPECT_TRUE(SameSite(one.placement.sites[a], placement.sites[a]));
        const double dx = one.placement.cart_x - placement.cart_x;
        const double dy = std::abs(one.placement.cart_y) - std::abs(placement.cart_y);
        EXPECT_EQ(one.placement.cart_yaw, placement.cart_yaw);
        if (std::abs(dx) > 1e-9) {
          EXPECT_NE(one.text.find(dx > 0 ? "toward the head" : "toward the feet"),
                    std::string::npos);
        } else {
          EXPECT_NE(one.text.find(dy < 0 ? "closer to the table" : "further from the table"),
                    std::string::npos);
        }
      }
    }
  }
  EXPECT_GT(found, 0);
}

}  // namespace
}  // namespace trocar::planners
