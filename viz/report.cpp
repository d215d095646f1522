#include "report.hpp"

#include <vtkBase64Utilities.h>

#include <algorithm>
#include <cmath>
#include <ctime>
#include <filesystem>
#include <functional>
#include <iomanip>
#include <sstream>

#include "common/error.hpp"
#include "common/file_util.hpp"
#include "plan/reachability.hpp"
#include "plan/signoff.hpp"
#include "port_placement/fixed_ports.hpp"
#include "scene.hpp"

namespace trocar::viz {
namespace {

std::string Escape(const std::string& text) {
  std::string out;
  for (char c : text) {
    switch (c) {
      case '&':
        out += "&amp;";
        break;
      case '<':
        out += "&lt;";
        break;
      case '>':
        out += "&gt;";
        break;
      case '"':
        out += "&quot;";
        break;
      default:
        out += c;
    }
  }
  return out;
}

std::string Base64(const std::string& bytes) {
  std::string out(bytes.size() * 4 / 3 + 8, '\0');
  const unsigned long n = vtkBase64Utilities::Encode(
      reinterpret_cast<const unsigned char*>(bytes.data()),
      static_cast<unsigned long>(bytes.size()), reinterpret_cast<unsigned char*>(out.data()));
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
td.reach-yes { background: #d7f5dc; }
.signature { margin-top: 18px; }
.signature span { display: inline-block; border-bottom: 1px solid #111; width: 220px; margin: 0 24px 0 6px; }
.print-only { display: none; }
/* The sign-off document (issue #43 item 7): printed from the browser (or headless Chromium's
   --print-to-pdf), the summary on the first page and each plan on a page of its own; the
   verified motions' long table stays in the HTML. */
@page { size: A4; margin: 10mm; }
@media print {
  body { margin: 0; font-size: 7.5pt; }
  h1 { font-size: 14pt; } h2 { font-size: 11pt; margin: 4px 0; } h3 { font-size: 9pt; margin: 4px 0; }
  .plan { break-before: page; border-top: none; margin-top: 0; padding-top: 0; }
  .pictures img { width: 32%; height: auto; margin: 2px 0.5% 2px 0; }
  table { margin: 3px 0; } td, th { padding: 1px 4px; }
  table.motions { display: none; }
  /* Long texts held to a few lines on paper (whole in the HTML): a reason in the reachability
     table two lines, a list of reasons its first three items. */
  span.why { display: -webkit-box; -webkit-line-clamp: 2; -webkit-box-orient: vertical; overflow: hidden; }
  ul.reasons li:nth-child(n+4) { display: none; }
  ul.reasons { margin: 2px 0; }
  .print-only { display: block; }
  table, .pictures, .signature { break-inside: avoid; }
  th, td.reach-yes, td.reach-no, td.reach-partly { -webkit-print-color-adjust: exact; print-color-adjust: exact; }
}
td.reach-no { background: #fbe0e0; }
td.reach-partly { background: #fff1c2; }
.unsuitable { color: #b42318; font-weight: bold; }
</style>)";

// Percent of a fraction, whole.
std::string Pct(double fraction) { return Num(100 * fraction, 0) + " %"; }

// Samples of `target` a plan's verified motions serve, "4 of 8".
std::string ServedOf(const planners::PlanFile& file, const planners::StoredPlan& p,
                     const std::string& target) {
  int of = 0, served = 0;
  for (std::size_t s = 0; s < file.samples.size(); ++s) {
    if (file.samples[s].target != target) continue;
    ++of;
    served += s < p.verified_served.size() && p.verified_served[s] ? 1 : 0;
  }
  return std::to_string(served) + " of " + std::to_string(of);
}

// The ports (in anatomical terms, then the coordinates tools use), the score's terms with their
// units and weights, and the verified motions of one plan.
void PlanTables(const planners::PlanFile& file, const planners::StoredPlan& p,
                std::ostringstream& h) {
  h << "<table class=\"ports\"><tr><th>arm</th><th>port</th><th>incision (W, m)</th><th>pivot (W, "
       "m)</th></tr>";
  for (const auto& port : p.ports) {
    h << "<tr><td>" << Escape(port.arm) << "</td><td>"
      << Escape(port.anatomy.empty() ? port.candidate : port.anatomy) << "</td><td>"
      << Num(port.p_W.x(), 3) << ", " << Num(port.p_W.y(), 3) << ", " << Num(port.p_W.z(), 3)
      << "</td><td>" << Num(port.rcm_W.x(), 3) << ", " << Num(port.rcm_W.y(), 3) << ", "
      << Num(port.rcm_W.z(), 3) << "</td></tr>";
  }
  h << "</table>\n<table class=\"terms\"><tr><th>term</th><th>value</th><th>unit</th><th>score "
       "(0-1)</th><th>weight</th></tr>";
  for (const auto& t : p.terms) {
    h << "<tr><td>" << Escape(t.name) << "</td><td>" << Num(t.value, 3) << "</td><td>"
      << Escape(t.unit) << "</td><td>" << Num(t.score, 3) << "</td><td>" << Num(t.weight, 2)
      << "</td></tr>";
  }
  h << "</table>\n";
  if (p.verified) {
    h << "<p>verified motions: coverage " << Pct(p.verified_coverage) << " (claimed "
      << Pct(p.claimed_coverage) << ", " << (p.verified_coverage >= p.claimed_coverage ? "+" : "")
      << Num(100 * (p.verified_coverage - p.claimed_coverage), 0)
      << " points by verification), samples served " << Pct(p.served_fraction) << ": <span class=\""
      << (p.verified_suitable ? "suitable" : "unsuitable") << "\">"
      << (p.verified_suitable ? "suitable" : "not suitable") << "</span></p><ul class=\"reasons\">";
    for (const auto& r : p.verification_reasons) h << "<li>" << Escape(r) << "</li>";
    h << "</ul>\n<table "
         "class=\"motions\"><tr><th>arm</th><th>sample</th><th>target</th><th>outcome</"
         "th><th>clearance (mm)</th><th>reason</th></tr>";
    for (const auto& m : p.motions) {
      const std::string target =
          m.sample < static_cast<int>(file.samples.size()) ? file.samples[m.sample].target : "";
      h << "<tr><td>" << Escape(m.arm) << "</td><td>" << m.sample << "</td><td>" << Escape(target)
        << "</td><td>" << Escape(m.outcome) << "</td><td>"
        << (m.solved && std::isfinite(m.min_clearance) ? Num(1000 * m.min_clearance, 1) : "")
        << "</td><td>" << Escape(m.reason) << "</td></tr>";
    }
    h << "</table>\n<p class=\"print-only\">the verified motions, one per arm and sample, are "
         "listed in the HTML report</p>\n";
  }
}

// Which arm reaches which stretch of each target, and which the endoscope sees (issue #43 item
// 5): a row per stretch, from planners::TargetReachability.
void ReachTable(const planners::Reachability& reach, const planners::PlanFile& file,
                std::ostringstream& h) {
  h << "<h3>Reachability on the targets</h3>\n<p>"
    << (reach.verified ? "by the plan's verified motions (instruments) and the endoscope's view"
                       : "by the plan's own reach check (not verified by motions)")
    << "; a stretch is where no arm's answer changes along the target.</p>\n"
    << "<table class=\"reach\"><tr><th>target</th><th>stretch</th><th>level</th>";
  for (const auto& arm : file.arms)
    h << "<th>" << Escape(arm.name) << (arm.role == "endoscope" ? " sees" : " reaches") << "</th>";
  h << "<th>served</th></tr>";
  for (const planners::TargetStretch& st : reach.stretches) {
    h << "<tr><td>" << Escape(st.target) << "</td><td>" << Escape(planners::StretchText(st)) << " ("
      << st.samples.size() << " sample" << (st.samples.size() > 1 ? "s" : "") << ")</td><td>"
      << Escape(st.level) << "</td>";
    for (const auto& arm : st.arms) {
      h << "<td class=\""
        << (arm.reaches ? "reach-yes\">yes"
                        : "reach-no\">no: <span class=\"why\">" + Escape(arm.why_not) + "</span>")
        << "</td>";
    }
    const char* cls = st.reach == planners::ReachClass::kServed   ? "reach-yes\">served"
                      : st.reach == planners::ReachClass::kPartly ? "reach-partly\">partly"
                                                                  : "reach-no\">no";
    h << "<td class=\"" << cls << "</td></tr>";
  }
  h << "</table>\n";
}

// A column's served stretches, per target: "LAD 0–45 mm, 60–90 mm; LIMA none".
std::string ServedStretches(const planners::Reachability& reach,
                            const std::vector<std::string>& targets) {
  std::ostringstream s;
  for (std::size_t t = 0; t < targets.size(); ++t) {
    std::vector<std::string> parts;
    for (const auto& st : reach.stretches) {
      if (st.target != targets[t] || !st.served) continue;
      const long from = std::lround(st.from_m * 1e3), to = std::lround(st.to_m * 1e3);
      parts.push_back(from == to ? std::to_string(from)
                                 : std::to_string(from) + "–" + std::to_string(to));
    }
    s << (t ? "; " : "") << targets[t] << " ";
    if (parts.empty()) s << "none";
    for (std::size_t i = 0; i < parts.size(); ++i) s << (i ? ", " : "") << parts[i];
    if (!parts.empty()) s << " mm";
  }
  return s.str();
}

// The plans shown and the placed baselines in columns (issue #43 item 6): ports by space, score,
// verified and claimed coverage, served samples per target, the verified verdict, the sign-off.
void Comparison(const planners::PlanFile& file, std::size_t shown, std::ostringstream& h) {
  struct Column {
    std::string title;
    const planners::StoredPlan* plan;
    std::string decision;
  };
  std::vector<Column> columns;
  for (std::size_t k = 0; k < shown; ++k)
    columns.push_back({"plan " + std::to_string(file.plans[k].rank), &file.plans[k],
                       planners::PlanDecisionStatus(file, k)});
  for (const auto& b : file.baselines) {
    if (b.placed) columns.push_back({b.kind + ": " + b.name, &b.plan, "(baseline)"});
  }
  std::vector<std::string> targets;
  for (const auto& s : file.samples)
    if (std::find(targets.begin(), targets.end(), s.target) == targets.end())
      targets.push_back(s.target);
  h << "<h2>Plans compared</h2>\n<table class=\"compare\"><tr><th></th>";
  for (const auto& c : columns) h << "<th>" << Escape(c.title) << "</th>";
  h << "</tr>";
  auto row = [&](const std::string& name, const std::function<std::string(const Column&)>& cell) {
    h << "<tr><td><b>" << Escape(name) << "</b></td>";
    for (const auto& c : columns) h << "<td>" << cell(c) << "</td>";
    h << "</tr>";
  };
  for (std::size_t a = 0; a < file.arms.size(); ++a) {
    row(file.arms[a].name + " port", [&](const Column& c) {
      const auto& port = c.plan->ports[a];
      return Escape(port.anatomy.empty() ? port.candidate : port.anatomy);
    });
  }
  row("at the nominal pose", [](const Column& c) { return Escape(c.plan->status); });
  row("score (0-1)", [](const Column& c) { return Num(c.plan->score, 3); });
  row("motions verified (claimed)", [](const Column& c) {
    return c.plan->verified
               ? Pct(c.plan->verified_coverage) + " (" + Pct(c.plan->claimed_coverage) + ")"
               : std::string("not verified");
  });
  row("samples served, verified", [](const Column& c) {
    return c.plan->verified ? Pct(c.plan->served_fraction) : std::string("not verified");
  });
  for (const auto& t : targets) {
    row(t + " samples served", [&](const Column& c) {
      return c.plan->verified_served.empty() ? std::string("-") : ServedOf(file, *c.plan, t);
    });
  }
  row("served stretches (from each target's origin)", [&](const Column& c) {
    return Escape(ServedStretches(planners::TargetReachability(file, *c.plan), targets));
  });
  row("verdict (verified motions)", [](const Column& c) {
    if (!c.plan->verified) return std::string("not verified");
    return std::string("<span class=\"") +
           (c.plan->verified_suitable ? "suitable\">suitable" : "unsuitable\">not suitable") +
           "</span>";
  });
  row("sign-off", [](const Column& c) { return Escape(c.decision); });
  h << "</table>\n";
}

}  // namespace

std::string WriteReport(ViewInputs inputs, const std::string& dir, const ReportOptions& options) {
  TROCAR_THROW_UNLESS(!inputs.plan.empty(), "report: no plan file given");
  TROCAR_OPTION_UNLESS(options.max_plans >= 1, "max_plans",
                       options.max_plans << ", expected at least 1");
  if (inputs.case_dir.empty()) inputs.case_dir = planners::ReadPlanFile(inputs.plan).case_dir;
  inputs.plan_index = 1;
  LoadedView view = LoadView(inputs);
  const planners::PlanFile& file = *view.plan;
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  TROCAR_THROW_UNLESS(
      std::filesystem::is_directory(dir),
      dir << ": cannot create the report's folder" << (ec ? ": " + ec.message() : ""));
  std::ostringstream h;
  h << "<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>trocar report: "
    << Escape(file.patient_name) << "</title>" << kStyle << "</head><body>\n";
  h << "<h1>Port placement report: " << Escape(file.patient_name) << "</h1>\n";
  h << "<p>plan file " << Escape(file.path) << "; case " << Escape(file.case_dir) << "; robot "
    << Escape(file.robot_file) << "</p>\n";
  // One verdict that counts (the verified one when the plans were verified), the claimed one
  // beside it, each labelled (issue #43 item 6).
  h << "<h2>Verdict</h2>";
  if (file.has_verified_verdict) {
    h << "<p>by verified motions (the verdict that counts): <span class=\""
      << (file.verified_suitable ? "suitable" : "unsuitable") << "\">"
      << Escape(file.verified_summary) << "</span></p><ul class=\"reasons\">";
    for (const auto& r : file.verified_reasons) h << "<li>" << Escape(r) << "</li>";
    h << "</ul>\n";
  }
  h << "<p>" << (file.has_verified_verdict ? "claimed, by the plans' own reach checks: " : "")
    << "<span class=\"" << (file.suitable ? "suitable" : "unsuitable") << "\">"
    << Escape(file.summary) << "</span></p><ul class=\"reasons\">";
  for (const auto& r : file.reasons) h << "<li>" << Escape(r) << "</li>";
  h << "</ul>\n";
  const std::size_t shown =
      std::min<std::size_t>(file.plans.size(), static_cast<std::size_t>(options.max_plans));
  // A stretch's level in the patient's intercostal spaces, when they are numbered.
  const planners::LevelText level = [&](const std::vector<Eigen::Vector3d>& p_W) {
    const std::string spaces = planners::SpacesAtLevel(*view.patient, p_W);
    return spaces.empty() ? spaces : "at the " + spaces;
  };
  Comparison(file, shown, h);
  // The sign-off block of the printed document: each plan's current decision, and lines to sign.
  h << "<h2>Sign-off</h2>\n";
  bool any_decision = false;
  for (std::size_t k = 0; k < file.plans.size(); ++k) {
    if (file.plans[k].signoffs.empty()) continue;
    any_decision = true;
    const planners::SignOff& last = file.plans[k].signoffs.back();
    h << "<p>plan " << file.plans[k].rank << ": <b>"
      << Escape(planners::PlanDecisionStatus(file, k)) << "</b> (" << Escape(last.decision)
      << " by " << Escape(last.surgeon) << " at " << Escape(last.time)
      << (last.override_reason.empty() ? "" : "; an override: " + Escape(last.override_reason))
      << ")</p>\n";
  }
  if (!any_decision)
    h << "<p>no plan signed off yet (trocar signoff, or the workstation's Approve)</p>\n";
  h << "<div "
       "class=\"signature\">surgeon<span></span>signature<span></span>date<span></span></div>\n";
  for (std::size_t k = 0; k < shown; ++k) {
    const planners::StoredPlan& p = file.plans[k];
    view.scene->ShowPlan(file, k);
    planners::PlanCollisions collisions(*view.patient, view.robot, file, k);
    const planners::PoseCollisions pose = collisions.Check(*view.scene->robot_state());
    view.scene->HighlightLinks(pose.colliding_links, pose.near_links);
    h << "<div class=\"plan\"><h2>Plan " << p.rank << ": " << Escape(p.status) << ", score "
      << Num(p.score, 3) << "</h2>\n<div class=\"pictures\">";
    Views external = {
        {ViewSpec{}, view.scene->ExternalCamera(double(options.width) / options.height)}};
    h << ImgTag(EncodePng(Render(*view.scene, external, options.width, options.height)),
                "plan " + std::to_string(p.rank) + ": external view");
    if (!p.views.empty()) {
      ViewSpec scope;
      scope.kind = ViewSpec::Kind::kEndoscope;
      FrameCamera used;
      const CameraPose camera =
          ViewCamera(*view.scene, scope, double(options.width) / options.height, &p, &used);
      scope.camera = used;
      h << ImgTag(EncodePng(Render(*view.scene, {{scope, camera}}, options.width, options.height)),
                  "plan " + std::to_string(p.rank) + ": endoscope view");
    }
    // A picture of one framing with only some groups shown, the others' visibility restored
    // after (the reach groups shown only where asked).
    auto picture = [&](Scene::Framing framing, ViewSpec::Kind kind,
                       const std::function<bool(const std::string&)>& shown,
                       const std::string& alt) {
      std::vector<std::pair<std::string, bool>> before;
      for (const std::string& g : view.scene->groups()) {
        before.push_back({g, view.scene->style().Visible(g)});
        if (!shown(g))
          view.scene->SetVisible(g, false);
        else if (g.rfind("reach:", 0) == 0)
          view.scene->SetVisible(g, true);
      }
      ViewSpec spec;
      spec.kind = kind;
      const Views views = {
          {spec, view.scene->ExternalCamera(double(options.width) / options.height, framing)}};
      h << ImgTag(EncodePng(Render(*view.scene, views, options.width, options.height)),
                  "plan " + std::to_string(p.rank) + ": " + alt);
      for (const auto& [g, visible] : before) view.scene->SetVisible(g, visible);
    };
    auto is_reach = [](const std::string& g) { return g.rfind("reach:", 0) == 0; };
    // The ports on the chest, close: skin, ribs and spaces, without the robot.
    picture(
        Scene::Framing::kPorts, ViewSpec::Kind::kPorts,
        [&](const std::string& g) {
          return g != "robot" && g != "cones" && g != "pivots" && !is_reach(g);
        },
        "ports on the chest");
    // The targets coloured along their length by how the plan serves them, with the heart and
    // the ports (the targets' own tubes hidden: the reach tubes cover them whole, in other
    // colours).
    view.scene->ShowReachability(file, k);
    picture(
        Scene::Framing::kTargets, ViewSpec::Kind::kTargets,
        [&](const std::string& g) { return g == "heart" || g == "ports" || is_reach(g); },
        "reachability on the targets");
    for (const char* g : {"reach:served", "reach:partly", "reach:none", "reach:labels"})
      view.scene->SetVisible(g, false);
    h << "</div>\n<p>nominal pose: " << Escape(Describe(pose)) << "</p>\n";
    ReachTable(planners::TargetReachability(file, k, level), file, h);
    PlanTables(file, p, h);
    h << "<h3>Sign-off</h3>";
    h << "<p>status: <b>" << Escape(planners::PlanDecisionStatus(file, k)) << "</b></p>";
    const std::vector<std::string> blockers = planners::ApprovalBlockers(file, k);
    if (!blockers.empty()) {
      h << "<p>approval needs an override:</p><ul class=\"reasons\">";
      for (const auto& b : blockers) h << "<li>" << Escape(b) << "</li>";
      h << "</ul>";
    }
    if (p.signoffs.empty()) h << "<p>not signed off</p>";
    for (const auto& s : p.signoffs) {
      h << "<p><b>" << Escape(s.decision) << "</b> by " << Escape(s.surgeon) << " at "
        << Escape(s.time) << (s.note.empty() ? "" : ": " + Escape(s.note)) << "</p>";
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
          if (IsRegularFile(f))
            h << "<div class=\"pictures\">" << ImgTag(ReadBinaryFile(f), figure) << "</div>";
        }
      }
    }
    h << "</div>\n";
  }
  if (shown < file.plans.size())
    h << "<p>" << file.plans.size() - shown << " more plans in the plan file.</p>";
  // What a surgeon would have done, judged the same way (issue #41 item 3).
  for (const auto& b : file.baselines) {
    h << "<div class=\"plan\"><h2>Baseline, " << Escape(b.kind) << ": " << Escape(b.name)
      << "</h2>\n";
    if (!b.placed) {
      h << "<p>not placed: " << Escape(b.why_not) << "</p></div>\n";
      continue;
    }
    h << "<p>ports as given:</p><ul>";
    for (const auto& w : b.where) h << "<li>" << Escape(w) << "</li>";
    h << "</ul><p>" << Escape(b.plan.status) << ", score " << Num(b.plan.score, 3)
      << "; its own verdict: <span class=\"" << (b.suitable ? "suitable" : "unsuitable") << "\">"
      << Escape(b.summary) << "</span></p><ul class=\"reasons\">";
    for (const auto& r : b.reasons) h << "<li>" << Escape(r) << "</li>";
    h << "</ul>\n";
    ReachTable(planners::TargetReachability(file, b.plan, level), file, h);
    PlanTables(file, b.plan, h);
    h << "</div>\n";
  }
  h << "</body></html>\n";
  const std::string path = (std::filesystem::path(dir) / "report.html").string();
  WriteFileAtomically(path, h.str());
  return path;
}

}  // namespace trocar::viz
