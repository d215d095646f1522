// The sign-off rule (issue #43 item 1): a plan that fails cannot be approved without an override
// with its reason, and a plan's status follows from its history.
#include <string>

#include <gtest/gtest.h>

#include "common/error.hpp"
#include "plan/plan_file.hpp"
#include "plan/signoff.hpp"

namespace trocar {
namespace {

using planners::ApprovalBlockers;
using planners::PlanDecisionStatus;
using planners::PlanFile;
using planners::SignOff;
using planners::StoredPlan;

StoredPlan Good() {
  StoredPlan p;
  p.status = "placed";
  p.verified = true;
  p.verified_suitable = true;
  p.verified_coverage = 0.95;
  p.served_fraction = 0.9;
  return p;
}

SignOff Decision(const std::string& decision, const std::string& time) {
  SignOff s;
  s.decision = decision;
  s.surgeon = "Dr Ada";
  s.time = time;
  return s;
}

TEST(SignOffRule, EachWayAPlanFailsBlocksItsApprovalAndAGoodPlanHasNoBlocker) {
  PlanFile file;
  file.path = "plan.json";
  file.plans = {Good(), Good(), Good(), Good()};
  file.plans[1].status = "in collision";
  file.plans[2].verified = false;
  file.plans[3].verified_suitable = false;
  file.plans[3].verified_coverage = 0.47;
  file.plans[3].served_fraction = 0.06;
  file.plans[3].verification_reasons = {"LAD: 0 of 8 samples served"};
  EXPECT_TRUE(ApprovalBlockers(file, 0).empty());
  const auto collision = ApprovalBlockers(file, 1);
  ASSERT_EQ(collision.size(), 1u);
  EXPECT_NE(collision[0].find("in collision"), std::string::npos) << collision[0];
  const auto unverified = ApprovalBlockers(file, 2);
  ASSERT_EQ(unverified.size(), 1u);
  EXPECT_NE(unverified[0].find("not verified"), std::string::npos) << unverified[0];
  const auto unsuitable = ApprovalBlockers(file, 3);
  ASSERT_EQ(unsuitable.size(), 1u);
  for (const char* says : {"not suitable", "47 %", "6 %", "LAD: 0 of 8"})
    EXPECT_NE(unsuitable[0].find(says), std::string::npos) << says << " in " << unsuitable[0];
  // A plan in collision and unverified: both said.
  file.plans[1].verified = false;
  EXPECT_EQ(ApprovalBlockers(file, 1).size(), 2u);
  EXPECT_THROW(ApprovalBlockers(file, 4), Error);
}

TEST(SignOffRule, TheStatusIsTheLatestDecisionAndALaterApprovalElsewhereSupersedes) {
  PlanFile file;
  file.plans = {Good(), Good(), Good()};
  EXPECT_EQ(PlanDecisionStatus(file, 0), "proposed");
  file.plans[0].signoffs = {Decision("approved", "2026-11-27T10:00:00Z")};
  EXPECT_EQ(PlanDecisionStatus(file, 0), "approved");
  file.plans[0].signoffs.push_back(Decision("rejected", "2026-11-27T11:00:00Z"));
  EXPECT_EQ(PlanDecisionStatus(file, 0), "rejected");
  file.plans[0].signoffs.push_back(Decision("approved", "2026-11-27T12:00:00Z"));
  EXPECT_EQ(PlanDecisionStatus(file, 0), "approved");
  // Plan 2 approved later: plan 1 superseded; an earlier approval elsewhere supersedes nothing.
  file.plans[1].signoffs = {Decision("approved", "2026-11-27T13:00:00Z")};
  file.plans[2].signoffs = {Decision("approved", "2026-11-27T09:00:00Z")};
  EXPECT_EQ(PlanDecisionStatus(file, 0), "superseded");
  EXPECT_EQ(PlanDecisionStatus(file, 1), "approved");
  EXPECT_EQ(PlanDecisionStatus(file, 2), "superseded");
  // Plan 2's approval withdrawn (rejected): plan 1's stands again.
  file.plans[1].signoffs.push_back(Decision("rejected", "2026-11-27T14:00:00Z"));
  EXPECT_EQ(PlanDecisionStatus(file, 0), "approved");
  EXPECT_EQ(PlanDecisionStatus(file, 1), "rejected");
}

}  // namespace
}  // namespace trocar
