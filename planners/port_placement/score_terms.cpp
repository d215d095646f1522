#include "port_placement/score_terms.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace trocar::planners {
namespace {

constexpr double kRadiansPerDegree = M_PI / 180.0;

// Score of the angle between two instruments (deg): 1 at 60, 0.5 at 45 and 75, 0 at 15 and 105.
double TriangulationScore(double deg) {
  const double off = std::abs(deg - 60.0);
  if (off <= 15.0) return 1.0 - off / 30.0;
  return std::max(0.0, 0.5 - (off - 15.0) / 60.0);
}

// Score of the approach angle against the target's normal: 1 within 30 deg, 0 at 90 deg.
double ApproachScore(double rad) {
  const double deg = rad / kRadiansPerDegree;
  return std::clamp((90.0 - deg) / 60.0, 0.0, 1.0);
}

// The instruments' reached (arm, sample) pairs, summed over: their count, and the sums of
// dexterity, approach score and approach angle (deg), instruments in arm order, samples in order.
struct Reached {
  int count = 0;
  double dexterity = 0.0, approach = 0.0, approach_deg = 0.0;
  double slots = 1.0;  // instrument-sample pairs, at least 1
};

Reached SumReached(const TermInputs& in) {
  Reached r;
  const int ns = static_cast<int>(in.samples.size());
  for (int a : in.instruments) {
    for (int s = 0; s < ns; ++s) {
      const SampleReach& reach = in.reach[a][s];
      if (!reach.reached) continue;
      ++r.count;
      r.dexterity += reach.dexterity;
      r.approach += ApproachScore(reach.approach);
      r.approach_deg += reach.approach / kRadiansPerDegree;
    }
  }
  r.slots = std::max<double>(1, in.instruments.size() * ns);
  return r;
}

TermValue Coverage(const TermInputs& in) {
  const Reached r = SumReached(in);
  const double coverage = r.count / r.slots;
  return {coverage, coverage, ""};
}

TermValue Served(const TermInputs& in) {
  const int ns = static_cast<int>(in.samples.size());
  const double served =
      ns > 0 ? static_cast<double>(std::count(in.served.begin(), in.served.end(), true)) / ns : 0.0;
  return {served, served, ""};
}

TermValue Dexterity(const TermInputs& in) {
  const Reached r = SumReached(in);
  const double per_reached = std::max(1, r.count);
  return {r.dexterity / per_reached, r.dexterity / per_reached * (r.count / r.slots), ""};
}

TermValue Approach(const TermInputs& in) {
  const Reached r = SumReached(in);
  const double per_reached = std::max(1, r.count);
  return {r.count ? r.approach_deg / per_reached : 90.0, r.approach / r.slots, ""};
}

// Between the first two instruments, at every sample (geometric: from the ports).
TermValue Triangulation(const TermInputs& in) {
  if (in.instruments.size() < 2) return {0.0, 1.0, "fewer than two instruments: not applicable"};
  const int ns = static_cast<int>(in.samples.size());
  const Eigen::Vector3d p1 = in.placement.sites[in.instruments[0]].p_W,
                        p2 = in.placement.sites[in.instruments[1]].p_W;
  double tri_deg = 0, tri_score = 0;
  for (int s = 0; s < ns; ++s) {
    const Eigen::Vector3d a = (p1 - in.samples[s].p_W).normalized(),
                          b = (p2 - in.samples[s].p_W).normalized();
    const double deg = std::acos(std::clamp(a.dot(b), -1.0, 1.0)) / kRadiansPerDegree;
    tri_deg += deg;
    tri_score += TriangulationScore(deg);
  }
  tri_deg /= std::max(1, ns);
  tri_score /= std::max(1, ns);
  return {tri_deg, tri_score, ""};
}

TermValue Endoscope(const TermInputs& in) {
  if (in.scopes.empty()) return {0.0, 1.0, "no endoscope arm: not applicable"};
  const int ns = static_cast<int>(in.samples.size());
  int seen = 0;
  for (int s = 0; s < ns; ++s) {
    for (int a : in.scopes) {
      if (in.reach[a][s].seen) {
        ++seen;
        break;
      }
    }
  }
  const double share = static_cast<double>(seen) / std::max(1, ns);
  return {share, share, ""};
}

TermValue Spacing(const TermInputs& in) {
  const auto& sites = in.placement.sites;
  double spacing = std::numeric_limits<double>::infinity();
  for (std::size_t a = 0; a < sites.size(); ++a) {
    for (std::size_t b = a + 1; b < sites.size(); ++b)
      spacing = std::min(spacing, (sites[a].p_W - sites[b].p_W).norm());
  }
  if (!std::isfinite(spacing)) return {0.0, 1.0, "one port: not applicable"};
  return {spacing,
          (spacing - in.options.spacing_min) / (in.options.spacing_ideal - in.options.spacing_min),
          ""};
}

TermValue ClearanceArmArm(const TermInputs& in) {
  const double d = in.clearance_arm_arm;
  return {std::isfinite(d) ? d : -1.0, std::isfinite(d) ? d / in.options.clearance_scale : 1.0, ""};
}

TermValue ClearanceArmPatient(const TermInputs& in) {
  const double d = in.clearance_arm_patient;
  return {d, d / in.options.clearance_scale, ""};
}

TermValue ClearanceInstrumentRib(const TermInputs& in) {
  const double d = in.clearance_instrument_rib;
  return {std::isfinite(d) ? d : -1.0, std::isfinite(d) ? d / in.options.rib_clearance_scale : 1.0,
          ""};
}

}  // namespace

const std::vector<ScoreTermDefinition>& ScoreTermDefinitions() {
  static const std::vector<ScoreTermDefinition> terms = {
      {"coverage", "fraction", &ScoreWeights::coverage,
       "share of (instrument, target sample) pairs reached within joint and insertion limits, "
       "every arm collision-free",
       &Coverage},
      {"served", "fraction", &ScoreWeights::served,
       "share of target samples every instrument reaches and the endoscope (when there is one) "
       "sees: the two-handed work under vision the verdict asks for",
       &Served},
      {"dexterity", "1", &ScoreWeights::dexterity,
       "mean inverse condition number of the tool Jacobian at the reached samples (length 0.1 m), "
       "times coverage",
       &Dexterity},
      {"approach", "deg", &ScoreWeights::approach,
       "mean angle between instrument axis and the target's approach normal; score 1 within 30 "
       "deg, 0 at 90",
       &Approach},
      {"triangulation", "deg", &ScoreWeights::triangulation,
       "mean angle between the two instruments at the target samples; 60 ideal, 45-75 acceptable "
       "(score 0.5)",
       &Triangulation},
      {"endoscope", "fraction", &ScoreWeights::endoscope,
       "share of target samples inside the scope's field of view, in front of it, within its "
       "working distance",
       &Endoscope},
      {"spacing", "m", &ScoreWeights::spacing,
       "smallest distance between two ports; full score from 8 cm", &Spacing},
      {"clearance_arm_arm", "m", &ScoreWeights::clearance_arm_arm,
       "smallest distance between two arms at the nominal pose (-1: one arm); full score from 5 cm",
       &ClearanceArmArm},
      {"clearance_arm_patient", "m", &ScoreWeights::clearance_arm_patient,
       "smallest distance from an arm (not its instrument) to the patient at the nominal pose; "
       "full score from 5 cm",
       &ClearanceArmPatient},
      {"clearance_instrument_rib", "m", &ScoreWeights::clearance_instrument_rib,
       "smallest distance from a shaft's axis (4 cm either side of its pivot, aimed at the "
       "targets) to a rib; full score from 4 mm (-1: no ribs)",
       &ClearanceInstrumentRib},
  };
  return terms;
}

std::vector<ScoreTerm> EvaluateTerms(const TermInputs& in, const ScoreWeights& weights) {
  std::vector<ScoreTerm> out;
  for (const ScoreTermDefinition& d : ScoreTermDefinitions()) {
    const TermValue v = d.evaluate(in);
    const bool applies = v.not_applicable.empty();
    out.push_back({d.name, d.unit, v.value, std::clamp(v.score, 0.0, 1.0),
                   applies ? weights.*d.weight : 0.0, applies ? d.note : v.not_applicable});
  }
  return out;
}

}  // namespace trocar::planners
