#include "report.hpp"

#include <cmath>
#include <ctime>
#include <filesystem>
#include <iomanip>
#include <sstream>

#include <vtkBase64Utilities.h>

#include "common/error.hpp"
#include "common/file_util.hpp"
#include "scene.hpp"

namespace trocar::viz {
namespace {

std::string Escape(const std::string& text) {
  std::string out;
  for (char c : text) {
    switch (c) {
      case '&': out += "&amp;"; break;
      case '<': out += "&lt;"; break;
      case '>': out += "&gt;"; break;
      case '"': out += "&quot;"; break;
      default: out += c;
    }
  }
  return out;
}

std::string Base64(const std::string& bytes) {
  std::string out(bytes.size() * 4 / 3 + 8, '\0');
  const unsigned long n = vtkBase64Utilities::Encode(reinterpret_cast<const unsigned char*>(bytes.data()),
                                                     static_cast<unsigned long>(bytes.size()),
                                                     reinterpret_cast<unsigned char*>(out.data()));
  out.resize(n);
  return out;
}

std::string ImgTag(const std::string& png, const std::string& alt) {
  return "<img alt=\"" + Escape(alt) + "\" src=\"data:image/png;base64," + Base64(png) + "\">";
}

std::string Num(double v, int digits) {
  std::ostringstream s;
  s << std::fixed << std::setprecision(digits) << v;
  return s.str();
}

const char* kStyle = R"(<style>
body { font-family: sans-serif; margin: 24px; color: #111; background: #fff; }
h1 { margin-bottom: 4px; }
.plan { border-top: 3px solid #1f77b4; margin-top: 28px; padding-top: 8px; }
.pictures img { margin: 4px 8px 4px 0; border: 1px solid #999; }
table { border-collapse: collapse; margin: 8px 0; }
th { background: #1f77b4; color: #fff; padding: 3px 8px; text-align: left; }
td { border: 1px solid #bbb; padding: 2px 8px; }
.suitable { color: #1a7f37; font-weight: bold; }
.unsuitable { color: #b42318; font-weight: bold; }
</style>)";

}  // namespace

std::string WriteReport(ViewInputs inputs, const std::string& dir, const ReportOptions& options) {
  TROCAR_THROW_UNLESS(!inputs.plan.empty(), "report: no plan file given");
  TROCAR_OPTION_UNLESS(options.max_plans >= 1, "max_plans", options.max_plans << ", expected at least 1");
  if (inputs.case_dir.empty()) inputs.case_dir = planners::ReadPlanFile(inputs.plan).case_dir;
  inputs.plan_index = 1;
  LoadedView view = LoadView(inputs);
  const planners::PlanFile& file = *view.plan;
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  TROCAR_THROW_UNLESS(std::filesystem::is_directory(dir), dir << ": cannot create the report's folder"
                                                              << (ec ? ": " + ec.message() : ""));
  std::ostringstream h;
  h << "<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>trocar report: "
    << Escape(file.patient_name) << "</title>" << kStyle << "</head><body>\n";
  h << "<h1>Port placement report: " << Escape(file.patient_name) << "</h1>\n";
  h << "<p>plan file " << Escape(file.path) << "; case " << Escape(file.case_dir) << "; robot "
    << Escape(file.robot_file) << "</p>\n";
  h << "<h2>Verdict</h2><p class=\"" << (file.suitable ? "suitable" : "unsuitable") << "\">"
    << Escape(file.summary) << "</p><ul>";
  for (const auto& r : file.reasons) h << "<li>" << Escape(r) << "</li>";
  h << "</ul>\n";
  const std::size_t shown = std::min<std::size_t>(file.plans.size(), static_cast<std::size_t>(options.max_plans));
  for (std::size_t k = 0; k < shown; ++k) {
    const planners::StoredPlan& p = file.plans[k];
    view.scene->ShowPlan(file, k);
    planners::PlanCollisions collisions(*view.patient, view.robot, file, k);
    const planners::PoseCollisions pose = collisions.Check(*view.scene->robot_state());
    view.scene->HighlightLinks(pose.colliding_links, pose.near_links);
    h << "<div class=\"plan\"><h2>Plan " << p.rank << ": " << Escape(p.status) << ", score "
      << Num(p.score, 3) << "</h2>\n<div class=\"pictures\">";
    Views external = {{ViewSpec{}, view.scene->ExternalCamera(double(options.width) / options.height)}};
    h << ImgTag(EncodePng(Render(*view.scene, external, options.width, options.height)),
                "plan " + std::to_string(p.rank) + ": external view");
    if (!p.views.empty()) {
      ViewSpec scope;
      scope.kind = ViewSpec::Kind::kEndoscope;
      FrameCamera used;
      const CameraPose camera = ViewCamera(*view.scene, scope, double(options.width) / options.height, &p, &used);
      scope.camera = used;
      h << ImgTag(EncodePng(Render(*view.scene, {{scope, camera}}, options.width, options.height)),
                  "plan " + std::to_string(p.rank) + ": endoscope view");
    }
    h << "</div>\n<p>nominal pose: " << Escape(Describe(pose)) << "</p>\n";
    h << "<table class=\"terms\"><tr><th>term</th><th>value</th><th>score</th></tr>";
    for (const auto& t : p.terms)
      h << "<tr><td>" << Escape(t.name) << "</td><td>" << Num(t.value, 4) << "</td><td>" << Num(t.score, 3) << "</td></tr>";
    h << "</table>\n<table class=\"ports\"><tr><th>arm</th><th>candidate</th><th>incision (W, m)</th><th>pivot (W, m)</th></tr>";
    for (const auto& port : p.ports) {
      h << "<tr><td>" << Escape(port.arm) << "</td><td>" << Escape(port.candidate) << "</td><td>"
        << Num(port.p_W.x(), 3) << ", " << Num(port.p_W.y(), 3) << ", " << Num(port.p_W.z(), 3) << "</td><td>"
        << Num(port.rcm_W.x(), 3) << ", " << Num(port.rcm_W.y(), 3) << ", " << Num(port.rcm_W.z(), 3) << "</td></tr>";
    }
    h << "</table>\n";
    if (p.verified) {
      h << "<p>verified motions: coverage " << Num(100 * p.verified_coverage, 0) << " % (claimed "
        << Num(100 * p.claimed_coverage, 0) << " %, " << (p.verified_coverage >= p.claimed_coverage ? "+" : "")
        << Num(100 * (p.verified_coverage - p.claimed_coverage), 0) << " points by verification), samples served "
        << Num(100 * p.served_fraction, 0) << " %: <span class=\"" << (p.verified_suitable ? "suitable" : "unsuitable")
        << "\">" << (p.verified_suitable ? "suitable" : "not suitable") << "</span></p><ul>";
      for (const auto& r : p.verification_reasons) h << "<li>" << Escape(r) << "</li>";
      h << "</ul>\n<table class=\"motions\"><tr><th>arm</th><th>sample</th><th>target</th><th>outcome</th><th>clearance (mm)</th><th>reason</th></tr>";
      for (const auto& m : p.motions) {
        const std::string target = m.sample < static_cast<int>(file.samples.size()) ? file.samples[m.sample].target : "";
        h << "<tr><td>" << Escape(m.arm) << "</td><td>" << m.sample << "</td><td>" << Escape(target) << "</td><td>"
          << Escape(m.outcome) << "</td><td>" << (m.solved && std::isfinite(m.min_clearance) ? Num(1000 * m.min_clearance, 1) : "")
          << "</td><td>" << Escape(m.reason) << "</td></tr>";
      }
      h << "</table>\n";
    }
    h << "<h3>Sign-off</h3>";
    h << "<p>status: <b>" << Escape(planners::PlanDecisionStatus(file, k)) << "</b></p>";
    const std::vector<std::string> blockers = planners::ApprovalBlockers(file, k);
    if (!blockers.empty()) {
      h << "<p>approval needs an override:</p><ul>";
      for (const auto& b : blockers) h << "<li>" << Escape(b) << "</li>";
      h << "</ul>";
    }
    if (p.signoffs.empty()) h << "<p>not signed off</p>";
    for (const auto& s : p.signoffs) {
      h << "<p><b>" << Escape(s.decision) << "</b> by " << Escape(s.surgeon) << " at " << Escape(s.time)
        << (s.note.empty() ? "" : ": " + Escape(s.note)) << "</p>";
      if (!s.override_reason.empty()) {
        h << "<p>override: " << Escape(s.override_reason) << "</p><ul>";
        for (const auto& b : s.overridden) h << "<li>overrode: " << Escape(b) << "</li>";
        h << "</ul>";
      }
      if (!s.session.empty()) {
        // The session's tracking figures, written beside its record by trocar teleop --record.
        const std::filesystem::path folder = std::filesystem::path(s.session).parent_path();
        for (const char* figure : {"tracking.png", "errors.png"}) {
          const std::string f = (folder / figure).string();
          if (IsRegularFile(f)) h << "<div class=\"pictures\">" << ImgTag(ReadBinaryFile(f), figure) << "</div>";
        }
      }
    }
    h << "</div>\n";
  }
  if (shown < file.plans.size()) h << "<p>" << file.plans.size() - shown << " more plans in the plan file.</p>";
  h << "</body></html>\n";
  const std::string path = (std::filesystem::path(dir) / "report.html").string();
  WriteFileAtomically(path, h.str());
  return path;
}

}  // namespace trocar::viz
