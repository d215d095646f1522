#pragma once
/// @file
/// What would serve a stretch of a target the plan leaves unserved (issue #43 item 4: reasons a
/// surgeon can act on). The arm that fails there has its port moved to a neighbouring
/// intercostal space or along its own, or the cart is moved along or away from the table; each
/// changed placement is evaluated in full, exactly as a plan is (EvaluateFinalPlan), and the one
/// that reaches most of the stretch is said: "psm2's port one space higher (ICS-L4) reaches 2 of
/// these 3 samples (the plan would serve 9 of 16, now 7)".

#include <string>
#include <vector>

#include "port_placement/problem.hpp"

namespace trocar::planners {

/// A change to one placement that reaches (or, for an endoscope, sees) more of a stretch.
struct Remedy {
  enum class Kind { kPort, kCart };
  Kind kind = Kind::kPort;
  int arm = -1;           ///< the failing arm (problem.arms() index)
  Placement placement;    ///< the changed placement (one port or the cart moved)
  int reached = 0;        ///< the stretch's samples the arm reaches (sees) there
  int of = 0;             ///< the stretch's samples
  int served = 0;         ///< samples the changed plan serves (every target)
  int served_before = 0;  ///< samples the plan serves as it is
  /// The changed plan serves every sample outside the stretch the plan served (no trade).
  bool keeps = false;
  std::string text;  ///< "psm2's port one space higher (ICS-L4) reaches 2 of these 3 ..."
};

/// The best change for `arm` over the `stretch` (sample indices the plan's `evaluation` leaves
/// unserved), or none (`reached == 0`) when no neighbouring port or cart pose tried reaches any
/// of it. Tried: the arm's port on the two nearest other candidate curves (one space higher and
/// lower), nearest to where it is, and 3 cm either way along its own; the cart 10 and 20 cm
/// toward the head and the feet, and 10 cm toward and away from the table. Each is evaluated as
/// a final plan is (detailed, the setup-joint solver's full effort). Preferred: a change that
/// keeps every sample served elsewhere, then the most of the stretch reached, then the most
/// samples served, then the order above; a change that trades one stretch for another says so.
/// Deterministic; runs the candidates on up to `threads` threads.
Remedy FindRemedy(const PortPlacementProblem& problem, const Placement& placement,
                  const Evaluation& evaluation, int arm, const std::vector<int>& stretch,
                  int threads = 1);

/// The words for a changed port's place relative to where it was: "one space higher (ICS-L4)",
/// "30 mm further forward along ICS-L5". Exposed for the tests.
std::string DescribePortMove(const PortPlacementProblem& problem, const PortSite& from,
                             const PortSite& to);

}  // namespace trocar::planners
