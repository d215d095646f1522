#include "plan/signoff.hpp"

#include <algorithm>
#include <cmath>
#include <ctime>
#include <sstream>

#include "common/error.hpp"
#include "common/file_util.hpp"

namespace trocar::planners {
namespace {

std::string UtcNow() {
  const std::time_t now = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&now, &tm);
  char buffer[32];
  std::strftime(buffer, sizeof(buffer), "%Y-%m-%dT%H:%M:%SZ", &tm);
  return buffer;
}

}  // namespace

std::vector<std::string> ApprovalBlockers(const PlanFile& file, std::size_t index) {
  TROCAR_THROW_UNLESS(index < file.plans.size(), file.path << ": plan " << index + 1
                                                           << ": the file holds "
                                                           << file.plans.size() << " plans");
  const StoredPlan& plan = file.plans[index];
  std::vector<std::string> out;
  if (plan.status != "placed") {
    out.push_back("its nominal pose is " + plan.status +
                  (plan.status == "in collision" ? " (the arms cannot stand there)" : ""));
  }
  if (!plan.verified) {
    out.push_back(
        "it was not verified by motions (planned without verification: verify the plan file "
        "first)");
  } else if (!plan.verified_suitable) {
    std::ostringstream why;
    why << "not suitable by its verified motions: " << std::lround(100 * plan.verified_coverage)
        << " % of the instrument motions verified, " << std::lround(100 * plan.served_fraction)
        << " % of the target samples served";
    for (std::size_t k = 0; k < std::min<std::size_t>(2, plan.verification_reasons.size()); ++k)
      why << "; " << plan.verification_reasons[k];
    out.push_back(why.str());
  }
  return out;
}

std::string PlanDecisionStatus(const PlanFile& file, std::size_t index) {
  TROCAR_THROW_UNLESS(index < file.plans.size(), file.path << ": plan " << index + 1
                                                           << ": the file holds "
                                                           << file.plans.size() << " plans");
  const auto& mine = file.plans[index].signoffs;
  if (mine.empty()) return "proposed";
  if (mine.back().decision != "approved") return mine.back().decision;
  // Superseded when another plan's standing approval is later than this one's (ISO 8601 UTC
  // times order as text; a tie keeps both approved).
  for (std::size_t k = 0; k < file.plans.size(); ++k) {
    const auto& other = file.plans[k].signoffs;
    if (k == index || other.empty() || other.back().decision != "approved") continue;
    if (other.back().time > mine.back().time) return "superseded";
  }
  return "approved";
}

SignOff SignOffPlan(const std::string& path, std::size_t index, SignOff signoff) {
  TROCAR_THROW_UNLESS(
      signoff.decision == "approved" || signoff.decision == "rejected",
      path << ": sign-off decision '" << signoff.decision << "': expected approved or rejected");
  TROCAR_THROW_UNLESS(!signoff.surgeon.empty(), path << ": a sign-off names its surgeon");
  TROCAR_THROW_UNLESS(signoff.note.size() <= 10000, path << ": sign-off note of "
                                                         << signoff.note.size()
                                                         << " characters: at most 10,000");
  // The whole file is read and checked first: a sign-off is only added to a plan this trocar reads.
  const PlanFile file = ReadPlanFile(path);
  TROCAR_THROW_UNLESS(index < file.plans.size(), path << ": plan " << index + 1
                                                      << ": the file holds " << file.plans.size()
                                                      << " plans");
  // An approval is a decision that the plan can be operated on: one that fails is refused unless
  // the surgeon overrides, with a reason, recorded beside the failures overridden.
  const std::vector<std::string> blockers = ApprovalBlockers(file, index);
  TROCAR_THROW_UNLESS(signoff.override_reason.size() <= 10000,
                      path << ": override reason of " << signoff.override_reason.size()
                           << " characters: at most 10,000");
  if (signoff.decision == "approved" && !blockers.empty()) {
    if (signoff.override_reason.empty()) {
      std::ostringstream m;
      m << path << ": plan " << index + 1 << " cannot be approved: ";
      for (std::size_t k = 0; k < blockers.size(); ++k) m << (k ? "; and " : "") << blockers[k];
      m << ". Approve it anyway only with an override reason, which is recorded with the failures "
           "it overrides";
      throw OptionError("override_reason", m.str());
    }
    signoff.overridden = blockers;
  } else {
    TROCAR_THROW_UNLESS(signoff.override_reason.empty(),
                        path << ": plan " << index + 1 << ": an override is given but "
                             << (signoff.decision == "approved" ? "nothing blocks its approval"
                                                                : "a rejection needs none")
                             << "; leave it out");
    signoff.overridden.clear();
  }
  if (!signoff.session.empty()) {
    TROCAR_THROW_UNLESS(IsRegularFile(signoff.session),
                        path << ": sign-off session " << signoff.session << " does not exist");
    signoff.session_hash = HashFile(signoff.session);
  }
  signoff.time = UtcNow();
  // Through the plan file's one writer: the document read above, with the decision added.
  PlanFile signed_file = file;
  signed_file.plans[index].signoffs.push_back(signoff);
  WritePlanFile(path, signed_file);
  return signoff;
}

}  // namespace trocar::planners
