#pragma once
/// @file
/// The `plan:` section of a case's patient.yaml: which arms go through ports and in which role,
/// how densely targets are sampled, and the score weights. The command line overrides it.

#include <string>

#include "port_placement/problem.hpp"

namespace trocar::planners {

/// Reads `case_dir/patient.yaml`'s `plan:` section (when present) into `options`:
/// ```yaml
/// plan:
///   arms: [psm1, ecm, psm2]          # arms to place, by name or RCM frame (default: all)
///   roles: {ecm: endoscope}          # role overrides
///   samples_per_target: 8
///   standoff: 0.005                  # m
///   table_height: [0.79, 1.04]       # m, the heights the search may set the table to; or fixed
///   weights: {coverage: 0.35, dexterity: 0.1, approach: 0.1, triangulation: 0.1, endoscope: 0.15,
///             spacing: 0.05, clearance_arm_arm: 0.05, clearance_arm_patient: 0.05,
///             clearance_instrument_rib: 0.05}
/// ```
/// @throws trocar::Error naming the file, line and field for unknown fields or bad values.
void ReadPlanConfig(const std::string& case_dir, ProblemOptions* options);

}  // namespace trocar::planners
