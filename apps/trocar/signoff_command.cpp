// trocar signoff: a surgeon approves or rejects one of a plan file's ranked plans, with a note.
#include <iostream>
#include <memory>

#include "apps/trocar/commands.hpp"
#include "common/error.hpp"
#include "plan/plan_file.hpp"
#include "plan/signoff.hpp"

namespace trocar::apps {
namespace {

struct SignOffOptions {
  std::string plan_file;
  int plan = 1;
  bool approve = false, reject = false;
  planners::SignOff signoff;
};

}  // namespace

void AddSignOffCommand(CLI::App* app) {
  auto o = std::make_shared<SignOffOptions>();
  CLI::App* cmd = app->add_subcommand(
      "signoff", "Approve or reject one of a plan file's ranked plans, with a note: stored in the "
                 "plan file (rewritten atomically) with the time and the teleoperation session");
  cmd->add_option("plan_file", o->plan_file, "the plan.json")->required();
  cmd->add_option("--plan", o->plan, "which ranked plan (1: the best)")
      ->check(CLI::Range(1, 1000000))
      ->capture_default_str();
  auto* approve = cmd->add_flag("--approve", o->approve, "approve the plan");
  auto* reject = cmd->add_flag("--reject", o->reject, "reject the plan");
  approve->excludes(reject);
  cmd->add_option("--surgeon", o->signoff.surgeon, "who signs")->required();
  cmd->add_option("--note", o->signoff.note, "why (at most 10,000 characters)");
  cmd->add_option("--session", o->signoff.session,
                  "the recorded teleoperation session the plan was verified with (its hash is stored)");
  cmd->add_option("--override", o->signoff.override_reason,
                  "approve a plan that fails (in collision, not verified, or not suitable by its "
                  "verified motions) anyway, for this reason: recorded with the failures it "
                  "overrides; without it such an approval is refused");
  cmd->callback([o]() {
    TROCAR_THROW_UNLESS(o->approve || o->reject, "signoff: say --approve or --reject");
    planners::SignOff s = o->signoff;
    s.decision = o->approve ? "approved" : "rejected";
    const auto index = static_cast<std::size_t>(o->plan - 1);
    WithFlags({{"override_reason", "--override"}},
              [&] { s = planners::SignOffPlan(o->plan_file, index, s); });
    std::cout << o->plan_file << ": plan " << o->plan << " " << s.decision << " by " << s.surgeon
              << " at " << s.time << (s.session.empty() ? "" : ", session " + s.session) << "\n";
    if (!s.override_reason.empty()) {
      std::cout << "  overriding: " << s.override_reason << "\n";
      for (const auto& b : s.overridden) std::cout << "    " << b << "\n";
    }
    // The status as the file now says it (another plan approved earlier is now superseded).
    const planners::PlanFile file = planners::ReadPlanFile(o->plan_file);
    for (std::size_t k = 0; k < file.plans.size(); ++k) {
      const std::string status = planners::PlanDecisionStatus(file, k);
      if (status != "proposed") std::cout << "  plan " << k + 1 << ": " << status << "\n";
    }
  });
}

}  // namespace trocar::apps
