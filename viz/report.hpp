#pragma once
/// @file
/// The plan report (`trocar report PLAN.json --out DIR`): one self-contained HTML file (pictures
/// embedded as PNG data) with, for each ranked plan, its external and endoscope views, its score
/// breakdown, ports, verification and motions, its sign-offs with the tracking figures of their
/// teleoperation sessions, and the verdict. Written atomically.

#include <string>

#include "view_inputs.hpp"

namespace trocar::viz {

struct ReportOptions {
  int width = 640, height = 400;  ///< each picture
  int max_plans = 5;              ///< the best ones
};

/// Renders and writes `dir/report.html` (creating `dir`) for the plan of `inputs` (its case: the
/// plan's own unless `inputs.case_dir` names one). @return the report's path.
/// @throws trocar::Error as LoadView, and naming the path when it cannot be written.
std::string WriteReport(ViewInputs inputs, const std::string& dir, const ReportOptions& options = {});

}  // namespace trocar::viz
