#pragma once
/// @file
/// A surgeon's decision on a plan of a plan file: what blocks an approval, the plan's status
/// from its history, and adding a decision to the file (rewritten atomically through the plan
/// file's one writer, plan_file.hpp).

#include <cstddef>
#include <string>
#include <vector>

#include "plan/plan_file.hpp"

namespace trocar::planners {

/// Why plan `index` (0-based) of `file` may not be approved without an override: at its nominal
/// pose in collision or not placed; not verified by motions; not suitable by its verified verdict
/// (its verified motions and served samples, with the first reasons). Empty: nothing blocks.
/// @throws trocar::Error when the index is out of range.
std::vector<std::string> ApprovalBlockers(const PlanFile& file, std::size_t index);

/// A plan's current status derived from its sign-off history: "proposed" (never signed),
/// "approved", "rejected" (its latest decision), or "superseded" (approved, but another plan of
/// the file was approved after it and stands).
/// @throws trocar::Error when the index is out of range.
std::string PlanDecisionStatus(const PlanFile& file, std::size_t index);

/// Adds `signoff` (its time set now) to plan `index` (0-based) of the plan file at `path`, which
/// is rewritten atomically (temporary name, then rename): a crash leaves the previous file whole.
/// Everything else in the file is kept. @return the sign-off as written.
/// @throws trocar::Error naming the file when it is not a readable plan, the index is out of
/// range, the decision is not "approved" or "rejected", the surgeon is empty, the note is over
/// 10,000 characters, or the session file cannot be read; when approving a plan that
/// ApprovalBlockers blocks without `override_reason` (the error lists the blockers), or giving an
/// override where nothing is blocked or on a rejection.
SignOff SignOffPlan(const std::string& path, std::size_t index, SignOff signoff);

}  // namespace trocar::planners
