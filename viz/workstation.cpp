#include "workstation.hpp"

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <iomanip>
#include <iostream>
#include <sstream>

#include <QApplication>
#include <QCheckBox>
#include <QComboBox>
#include <QFileDialog>
#include <QFormLayout>
#include <QHBoxLayout>
#include <QLabel>
#include <QLineEdit>
#include <QListWidget>
#include <QMainWindow>
#include <QMenu>
#include <QMenuBar>
#include <QMessageBox>
#include <QPushButton>
#include <QScrollArea>
#include <QSlider>
#include <QSplitter>
#include <QStatusBar>
#include <QSurfaceFormat>
#include <QTabWidget>
#include <QTextBrowser>
#include <QTimer>
#include <QVBoxLayout>
#include <QVTKOpenGLNativeWidget.h>
#include <vtkCallbackCommand.h>
#include <vtkCamera.h>
#include <vtkGenericOpenGLRenderWindow.h>
#include <vtkInteractorStyleTrackballCamera.h>
#include <vtkNew.h>
#include <vtkObjectFactory.h>
#include <vtkRenderWindowInteractor.h>
#include <vtkRenderer.h>

#include <unistd.h>

#include "common/error.hpp"
#include "kinematics/forward_kinematics.hpp"
#include "plan/signoff.hpp"
#include "replay.hpp"
#include "scene_file.hpp"
#include "view_inputs.hpp"

namespace trocar::viz {
namespace {

/// VTK's trackball camera with the thesis' buttons: right pans, middle zooms.
class ThesisCameraStyle : public vtkInteractorStyleTrackballCamera {
 public:
  static ThesisCameraStyle* New();
  vtkTypeMacro(ThesisCameraStyle, vtkInteractorStyleTrackballCamera);
  void OnRightButtonDown() override {
    FindPokedRenderer(Interactor->GetEventPosition()[0], Interactor->GetEventPosition()[1]);
    if (CurrentRenderer) StartPan();
  }
  void OnRightButtonUp() override {
    if (State == VTKIS_PAN) EndPan();
  }
  void OnMiddleButtonDown() override {
    FindPokedRenderer(Interactor->GetEventPosition()[0], Interactor->GetEventPosition()[1]);
    if (CurrentRenderer) StartDolly();
  }
  void OnMiddleButtonUp() override {
    if (State == VTKIS_DOLLY) EndDolly();
  }
};
vtkStandardNewMacro(ThesisCameraStyle);

/// A joint's slider range: its limits, or a turn either way (half a metre) where they are open.
std::pair<double, double> SliderRange(const robot::Joint& joint) {
  const double open = joint.type == robot::JointType::kPrismatic ? 0.5 : M_PI;
  return {std::isfinite(joint.limits.lower) ? joint.limits.lower : -open,
          std::isfinite(joint.limits.upper) ? joint.limits.upper : open};
}

QString Fixed(double v, int digits) { return QString::number(v, 'f', digits); }

std::string PlanTitle(const planners::StoredPlan& p) {
  std::ostringstream s;
  s << p.rank << " · " << p.status << " · score " << std::fixed << std::setprecision(3) << p.score;
  if (p.verified) s << " · verified " << std::setprecision(0) << 100 * p.verified_coverage << " %";
  return s.str();
}

/// The selected plan's score breakdown, verdict and verification, as HTML.
QString PlanHtml(const planners::PlanFile& file, std::size_t index) {
  const planners::StoredPlan& p = file.plans.at(index);
  QString h;
  h += "<h3>Plan " + QString::number(p.rank) + ": " + QString::fromStdString(p.status) + "</h3>";
  h += "<p>score <b>" + Fixed(p.score, 3) + "</b>, rank score " + Fixed(p.rank_score, 3) + "</p>";
  h += "<p>ports:</p><ul>";
  for (const auto& port : p.ports) {
    h += "<li>" + QString::fromStdString(port.arm) + ": " +
         QString::fromStdString(port.anatomy.empty() ? port.candidate : port.anatomy).toHtmlEscaped() +
         "</li>";
  }
  h += "</ul>";
  h += "<table border=1 cellspacing=0 cellpadding=2><tr><th>term</th><th>value</th><th>unit</th>"
       "<th>score (0-1)</th><th>weight</th></tr>";
  for (const auto& t : p.terms) {
    h += "<tr><td>" + QString::fromStdString(t.name) + "</td><td>" + Fixed(t.value, 3) + "</td><td>" +
         QString::fromStdString(t.unit) + "</td><td>" + Fixed(t.score, 3) + "</td><td>" +
         Fixed(t.weight, 2) + "</td></tr>";
  }
  h += "</table>";
  if (p.verified) {
    h += "<p>verified coverage " + Fixed(100 * p.verified_coverage, 0) + " %, samples served " +
         Fixed(100 * p.served_fraction, 0) + " %: " +
         (p.verified_suitable ? "<b>suitable</b>" : "<b>not suitable</b>") + "</p><ul>";
    for (const auto& r : p.verification_reasons) h += "<li>" + QString::fromStdString(r).toHtmlEscaped() + "</li>";
    h += "</ul>";
  }
  if (file.has_verified_verdict) {
    h += "<h4>Verdict, by verified motions (the one that counts)</h4><p>" +
         QString::fromStdString(file.verified_summary).toHtmlEscaped() + "</p><ul>";
    for (const auto& r : file.verified_reasons) h += "<li>" + QString::fromStdString(r).toHtmlEscaped() + "</li>";
    h += "</ul>";
  }
  h += QString(file.has_verified_verdict ? "<h4>Verdict claimed by the plans' reach checks</h4><p>"
                                         : "<h4>Verdict (best plan)</h4><p>") +
       QString::fromStdString(file.summary).toHtmlEscaped() + "</p><ul>";
  for (const auto& r : file.reasons) h += "<li>" + QString::fromStdString(r).toHtmlEscaped() + "</li>";
  h += "</ul>";
  if (!p.message.empty()) h += "<p><i>" + QString::fromStdString(p.message).toHtmlEscaped() + "</i></p>";
  h += "<h4>Sign-off</h4>";
  h += "<p>status: <b>" + QString::fromStdString(planners::PlanDecisionStatus(file, index)) + "</b></p>";
  const std::vector<std::string> blockers = planners::ApprovalBlockers(file, index);
  if (!blockers.empty()) {
    h += "<p>Approve needs an override and its reason:</p><ul>";
    for (const auto& b : blockers) h += "<li>" + QString::fromStdString(b).toHtmlEscaped() + "</li>";
    h += "</ul>";
  }
  if (p.signoffs.empty()) h += "<p>not signed off</p>";
  for (auto it = p.signoffs.rbegin(); it != p.signoffs.rend(); ++it) {
    h += "<p><b>" + QString::fromStdString(it->decision) + "</b> by " +
         QString::fromStdString(it->surgeon).toHtmlEscaped() + " at " + QString::fromStdString(it->time) +
         (it->session.empty() ? QString() : ", session " + QString::fromStdString(it->session).toHtmlEscaped()) +
         (it->note.empty() ? QString() : ": " + QString::fromStdString(it->note).toHtmlEscaped()) +
         (it->override_reason.empty() ? QString()
                                      : "; <i>override</i>: " + QString::fromStdString(it->override_reason).toHtmlEscaped()) +
         "</p>";
  }
  return h;
}

class Workstation {
 public:
  Workstation(std::unique_ptr<Scene> scene, std::shared_ptr<const robot::RobotModel> robot,
              const planners::PlanFile* plan, const WorkstationOptions& options)
      : scene_(std::move(scene)), robot_(robot), options_(options) {
    if (plan) plan_ = std::make_unique<planners::PlanFile>(*plan);
    window_.setWindowTitle(QString::fromStdString("trocar — " + (scene_->patient() ? scene_->patient()->name : std::string("robot"))));
    window_.resize(options.width, options.height);
    auto* splitter = new QSplitter;
    auto* tabs = new QTabWidget;
    tabs->setMinimumWidth(330);
    tabs->addTab(BuildPlansTab(), "Plans");
    tabs->addTab(BuildStructuresTab(), "Structures");
    tabs->addTab(BuildRobotTab(), "Robot");
    tabs->addTab(BuildReplayTab(), "Replay");
    tabs->addTab(BuildViewTab(), "View");
    splitter->addWidget(tabs);
    vtk_widget_ = new QVTKOpenGLNativeWidget;
    render_window_ = vtkSmartPointer<vtkGenericOpenGLRenderWindow>::New();
    vtk_widget_->setRenderWindow(render_window_);
    AdaptAfterFirstFrame(render_window_);  // multisampling off under software rendering
    external_->SetViewport(0, 0, 0.5, 1);
    scope_->SetViewport(0.5, 0, 1, 1);
    scene_->AddTo(external_);
    scene_->AddTo(scope_);
    render_window_->AddRenderer(external_);
    render_window_->AddRenderer(scope_);
    // The external view's overlays (issue #43 item 2): the legend, and the orientation marker in
    // a corner renderer over it that turns with the external camera.
    if (scene_->ShowsOverlay("legend")) scene_->AddLegend(external_);
    if (scene_->ShowsOverlay("orientation")) {
      render_window_->SetNumberOfLayers(2);
      marker_->SetLayer(1);
      marker_->InteractiveOff();
      marker_->SetViewport(0, 0, 0.09, 0.16);
      scene_->AddOrientationMarker(marker_, ExternalPose());
      render_window_->AddRenderer(marker_);
      vtkNew<vtkCallbackCommand> follow;
      follow->SetClientData(this);
      follow->SetCallback([](vtkObject*, unsigned long, void* self, void*) {
        auto* w = static_cast<Workstation*>(self);
        const CameraPose view = w->ExternalPose();
        vtkCamera* c = w->marker_->GetActiveCamera();
        const Eigen::Vector3d eye = -5.8 * (view.focal_point - view.position).normalized();
        c->SetPosition(eye.data());
        c->SetFocalPoint(0, 0, 0);
        c->SetViewUp(view.view_up.data());
        c->OrthogonalizeViewUp();
      });
      external_->GetActiveCamera()->AddObserver(vtkCommand::ModifiedEvent, follow);
    }
    vtkNew<ThesisCameraStyle> style;
    style->SetDefaultRenderer(external_);
    render_window_->GetInteractor()->SetInteractorStyle(style);
    splitter->addWidget(vtk_widget_);
    splitter->setStretchFactor(1, 1);
    window_.setCentralWidget(splitter);
    QMenu* file_menu = window_.menuBar()->addMenu("&File");
    auto* open = file_menu->addAction("&Open plan…");
    auto* save_scene = file_menu->addAction("&Save scene…");
    auto* load_scene = file_menu->addAction("&Load scene…");
    QObject::connect(save_scene, &QAction::triggered, [this] {
      const QString path = QFileDialog::getSaveFileName(&window_, "Save scene", "", "Scenes (*.json)");
      if (!path.isEmpty()) SaveScene(path.toStdString());
    });
    QObject::connect(load_scene, &QAction::triggered, [this] {
      const QString path = QFileDialog::getOpenFileName(&window_, "Load scene", "", "Scenes (*.json)");
      if (!path.isEmpty()) LoadSceneFile(path.toStdString());
    });
    QObject::connect(open, &QAction::triggered, [this] {
      const QString path = QFileDialog::getOpenFileName(&window_, "Open plan", "", "Plans (*.json)");
      if (!path.isEmpty()) OpenPlan(path.toStdString());
    });
    if (plan_) SelectPlan(std::min<std::size_t>(options.plan_index, plan_->plans.size() - 1));
    UpdateScope();
    const double aspect = (scope_available_ ? 0.5 : 1.0) * options.width / options.height;
    Scene::Apply(options.camera ? *options.camera : scene_->ExternalCamera(aspect), external_);
    if (!plan_) window_.statusBar()->showMessage(QString::number(scene_->triangle_count()) + " triangles");
  }

  int Run(QApplication& app) {
    window_.show();
    if (!options_.grab_path.empty()) {
      QTimer::singleShot(300, [this, &app] {
        Render();
        const QImage image = window_.grab().toImage();
        const std::string tmp = options_.grab_path + ".tmp" + std::to_string(::getpid()) + ".png";
        if (!image.save(QString::fromStdString(tmp), "PNG")) {
          std::cerr << "error: " << options_.grab_path << ": cannot write the window's image\n";
          code_ = 1;
        } else {
          std::error_code ec;
          std::filesystem::rename(tmp, options_.grab_path, ec);
          if (ec) {
            std::cerr << "error: " << options_.grab_path << ": " << ec.message() << "\n";
            code_ = 1;
          }
        }
        app.quit();
      });
    }
    app.exec();
    return code_;
  }

 private:
  void Render() { render_window_->Render(); }

  void Fail(const std::string& what) {
    std::cerr << "error: " << what << "\n";
    window_.statusBar()->showMessage(QString::fromStdString("error: " + what));
    if (options_.grab_path.empty()) QMessageBox::warning(&window_, "trocar", QString::fromStdString(what));
  }

  QWidget* BuildPlansTab() {
    auto* w = new QWidget;
    auto* layout = new QVBoxLayout(w);
    plans_ = new QListWidget;
    plans_->setObjectName("plans");
    details_ = new QTextBrowser;
    layout->addWidget(new QLabel("Ranked plans"));
    layout->addWidget(plans_, 1);
    layout->addWidget(details_, 2);
    auto* sign = new QFormLayout;
    surgeon_ = new QLineEdit(QString::fromLocal8Bit(qgetenv("USER")));
    note_ = new QLineEdit;
    override_ = new QLineEdit;
    override_->setPlaceholderText("only to approve a plan that fails: why");
    sign->addRow("surgeon", surgeon_);
    sign->addRow("note", note_);
    sign->addRow("override", override_);
    layout->addLayout(sign);
    auto* buttons = new QHBoxLayout;
    approve_ = new QPushButton("Approve");
    auto* approve = approve_;
    auto* reject = new QPushButton("Reject");
    buttons->addWidget(approve);
    buttons->addWidget(reject);
    layout->addLayout(buttons);
    QObject::connect(override_, &QLineEdit::textChanged, [this] { UpdateApprove(); });
    QObject::connect(approve, &QPushButton::clicked, [this] { Sign("approved"); });
    QObject::connect(reject, &QPushButton::clicked, [this] { Sign("rejected"); });
    FillPlans();
    QObject::connect(plans_, &QListWidget::currentRowChanged, [this](int row) {
      if (row >= 0 && !filling_) SelectPlan(static_cast<std::size_t>(row));
    });
    return w;
  }

  void FillPlans() {
    filling_ = true;
    plans_->clear();
    if (plan_) {
      for (const auto& p : plan_->plans) plans_->addItem(QString::fromStdString(PlanTitle(p)));
    } else {
      details_->setHtml("<p>No plan: <code>trocar view CASE PLAN.json</code>, or File ▸ Open plan.</p>");
    }
    filling_ = false;
  }

  void SelectPlan(std::size_t k) {
    try {
      scene_->ShowPlan(*plan_, k);
      plan_index_ = k;
      collisions_ = std::make_unique<planners::PlanCollisions>(*scene_->patient(), robot_, *plan_, k);
      FillMotions();
      ShowCollisions();
      details_->setHtml(PlanHtml(*plan_, k));
      UpdateApprove();
      if (plans_->currentRow() != static_cast<int>(k)) plans_->setCurrentRow(static_cast<int>(k));
      SyncJoints();
      UpdateScope();
      Render();
    } catch (const Error& e) {
      Fail(e.what());
    }
  }

  /// Approve follows SignOffPlan's rule: active on a plan nothing blocks, or, on one that fails,
  /// once an override reason is typed; its tooltip says which.
  void UpdateApprove() {
    if (!approve_) return;
    if (!plan_ || plan_index_ >= plan_->plans.size()) {
      approve_->setEnabled(false);
      approve_->setToolTip("no plan");
      return;
    }
    const std::vector<std::string> blockers = planners::ApprovalBlockers(*plan_, plan_index_);
    QString why;
    for (const auto& b : blockers) why += QString::fromStdString(b) + "\n";
    const bool overridden = !override_->text().trimmed().isEmpty();
    approve_->setEnabled(blockers.empty() || overridden);
    approve_->setToolTip(blockers.empty() ? QString("approve this plan")
                                          : (overridden ? "approve with the override, overriding:\n"
                                                        : "type an override reason to approve; this plan fails:\n") +
                                                why);
  }

  /// Signs the shown plan off in its file (atomically), then shows the file as written.
  void Sign(const std::string& decision) {
    if (!plan_) return Fail("no plan to sign off: open a plan first");
    try {
      planners::SignOff s;
      s.decision = decision;
      s.surgeon = surgeon_->text().trimmed().toStdString();
      s.note = note_->text().toStdString();
      if (decision == "approved" && !planners::ApprovalBlockers(*plan_, plan_index_).empty())
        s.override_reason = override_->text().trimmed().toStdString();
      s = planners::SignOffPlan(plan_->path, plan_index_, s);
      plan_->plans[plan_index_].signoffs.push_back(s);
      details_->setHtml(PlanHtml(*plan_, plan_index_));
      window_.statusBar()->showMessage(QString::fromStdString("plan " + std::to_string(plan_index_ + 1) + " " +
                                                              decision + " in " + plan_->path));
    } catch (const Error& e) {
      Fail(e.what());
    }
  }

  /// The pose's collisions highlighted, and said in the replay tab and the status bar.
  void ShowCollisions() {
    if (!collisions_ || !scene_->robot_state()) return;
    const planners::PoseCollisions pose = collisions_->Check(*scene_->robot_state());
    scene_->HighlightLinks(pose.colliding_links, pose.near_links);
    const QString text = QString::fromStdString(Describe(pose));
    if (pose_label_) pose_label_->setText(text);
    window_.statusBar()->showMessage(text);
  }

  QWidget* BuildReplayTab() {
    auto* w = new QWidget;
    auto* layout = new QVBoxLayout(w);
    motions_ = new QComboBox;
    layout->addWidget(new QLabel("Verified motions of the plan"));
    layout->addWidget(motions_);
    auto* play = new QPushButton("Play");
    frame_slider_ = new QSlider(Qt::Horizontal);
    auto* row = new QHBoxLayout;
    row->addWidget(play);
    row->addWidget(frame_slider_, 1);
    layout->addLayout(row);
    pose_label_ = new QLabel;
    pose_label_->setWordWrap(true);
    layout->addWidget(pose_label_);
    layout->addStretch(1);
    timer_ = new QTimer(w);
    timer_->setInterval(33);
    QObject::connect(motions_, QOverload<int>::of(&QComboBox::currentIndexChanged), [this](int i) {
      if (!filling_) LoadMotion(i);
    });
    QObject::connect(frame_slider_, &QSlider::valueChanged, [this](int f) { ShowFrame(f); });
    QObject::connect(play, &QPushButton::clicked, [this, play] {
      if (timer_->isActive()) {
        timer_->stop();
        play->setText("Play");
      } else {
        // The motion shown in the list when the window opened was never loaded (the list fills
        // without loading): Play loads it first.
        if (frames_.empty()) LoadMotion(motions_->currentIndex());
        if (frames_.empty()) return;
        if (frame_slider_->value() >= frame_slider_->maximum()) frame_slider_->setValue(0);
        timer_->start();
        play->setText("Pause");
      }
    });
    QObject::connect(timer_, &QTimer::timeout, [this, play] {
      if (frame_slider_->value() >= frame_slider_->maximum()) {
        timer_->stop();
        play->setText("Play");
        return;
      }
      frame_slider_->setValue(frame_slider_->value() + 1);
    });
    return w;
  }

  void FillMotions() {
    if (!motions_) return;
    filling_ = true;
    motions_->clear();
    motion_index_.clear();
    frames_.clear();
    replayed_ = nullptr;
    const auto& motions = plan_->plans[plan_index_].motions;
    for (std::size_t i = 0; i < motions.size(); ++i) {
      const auto& m = motions[i];
      if (m.waypoints.empty() && m.failure_pose.size() == 0) continue;
      const std::string target =
          m.sample < static_cast<int>(plan_->samples.size()) ? plan_->samples[m.sample].target : "?";
      motions_->addItem(
          QString::fromStdString(m.arm + " to sample " + std::to_string(m.sample) + " (" + target +
                                 ")" + (m.solved ? "" : ": " + m.outcome + ", where it fails")));
      motion_index_.push_back(i);
    }
    if (motion_index_.empty()) motions_->addItem("none to replay");
    filling_ = false;
    frame_slider_->setRange(0, 0);
  }

  void LoadMotion(int i) {
    if (i < 0 || i >= static_cast<int>(motion_index_.size())) return;
    try {
      const auto& plan = plan_->plans[plan_index_];
      const robot::RobotState start =
          planners::NominalState(*scene_->robot(), plan, plan_->path + ": plan " + std::to_string(plan_index_ + 1));
      replayed_ = &plan.motions[motion_index_[i]];
      frames_ = ReplayMotion(*scene_->robot(), start, *replayed_, collisions_.get());
      FrameOnMovingArm();
      frame_slider_->setRange(0, static_cast<int>(frames_.size()) - 1);
      frame_slider_->setValue(0);
      ShowFrame(0);
    } catch (const Error& e) {
      Fail(e.what());
    }
  }

  /// The external camera framed on what the replayed motion moves (issue #43 item 2): the links
  /// whose place changes over its frames, all along it, and the sample it goes to; seen from
  /// where the camera looks now.
  void FrameOnMovingArm() {
    if (frames_.size() < 2) return;
    const auto& first = frames_.front().state.X_WL;
    std::vector<int> moving;
    for (const ReplayFrame& f : frames_)
      for (std::size_t l = 0; l < first.size() && l < f.state.X_WL.size(); ++l)
        if ((f.state.X_WL[l].translation() - first[l].translation()).norm() > 1e-4 &&
            std::find(moving.begin(), moving.end(), static_cast<int>(l)) == moving.end())
          moving.push_back(static_cast<int>(l));
    std::vector<Eigen::Vector3d> points;
    const std::size_t step = std::max<std::size_t>(1, frames_.size() / 20);
    for (std::size_t k = 0; k < frames_.size(); k += step)
      for (int l : moving) points.push_back(frames_[k].state.X_WL[l].translation());
    for (int l : moving) points.push_back(frames_.back().state.X_WL[l].translation());
    if (replayed_ && replayed_->sample >= 0 &&
        replayed_->sample < static_cast<int>(plan_->samples.size()))
      points.push_back(plan_->samples[replayed_->sample].p_W);
    if (points.empty()) return;
    const CameraPose now = ExternalPose();
    const CameraPose framed =
        FramePoints(points, Aspect(external_), now.position - now.focal_point, now.view_up);
    Scene::Apply(framed, external_);
  }

  void ShowFrame(int f) {
    if (f < 0 || f >= static_cast<int>(frames_.size())) return;
    const ReplayFrame& frame = frames_[f];
    scene_->SetRobotState(frame.state);
    scene_->HighlightLinks(frame.collisions.colliding_links, frame.collisions.near_links);
    QString text = "frame " + QString::number(f + 1) + " of " + QString::number(frames_.size()) +
                   ": " + QString::fromStdString(Describe(frame.collisions));
    // A failed motion's last frame is the pose that fails: its reason beside the collisions.
    if (replayed_ && !replayed_->solved && f + 1 == static_cast<int>(frames_.size()))
      text +=
          QString::fromStdString("\nfails here: " + replayed_->outcome + ": " + replayed_->reason);
    pose_label_->setText(text);
    window_.statusBar()->showMessage(text);
    SyncJoints();
    UpdateScope();
    Render();
  }

  CameraPose ExternalPose() const {
    CameraPose pose;
    vtkCamera* c = external_->GetActiveCamera();
    c->GetPosition(pose.position.data());
    c->GetFocalPoint(pose.focal_point.data());
    c->GetViewUp(pose.view_up.data());
    pose.view_angle_deg = c->GetViewAngle();
    return pose;
  }

  void SaveScene(const std::string& path) {
    try {
      ViewInputs in = options_.inputs;
      in.plan = plan_ ? plan_->path : "";
      in.plan_index = static_cast<int>(plan_index_) + 1;
      const CameraPose camera = ExternalPose();
      WriteSceneFile(path, CaptureScene(in, *scene_, &camera));
      window_.statusBar()->showMessage(QString::fromStdString("scene saved to " + path));
    } catch (const Error& e) {
      Fail(e.what());
    }
  }

  /// A scene of the case shown: its plan, robot pose, style and camera; another case's is
  /// refused (open it with trocar view --scene).
  void LoadSceneFile(const std::string& path) {
    try {
      const SceneFile file = ReadSceneFile(path);
      namespace fs = std::filesystem;
      std::error_code ec;
      TROCAR_THROW_UNLESS(fs::equivalent(file.inputs.case_dir, options_.inputs.case_dir, ec),
                          path << ": is a scene of " << file.inputs.case_dir
                               << ", not of the case shown: open it as a scene of its own case");
      if (!file.inputs.plan.empty() && (!plan_ || !fs::equivalent(file.inputs.plan, plan_->path, ec))) {
        OpenPlan(file.inputs.plan);
      }
      if (plan_ && file.inputs.plan_index >= 1 &&
          file.inputs.plan_index <= static_cast<int>(plan_->plans.size())) {
        SelectPlan(static_cast<std::size_t>(file.inputs.plan_index - 1));
      }
      ApplyScene(file, scene_.get());
      if (file.has_camera) Scene::Apply(file.camera, external_);
      ShowCollisions();
      SyncJoints();
      UpdateScope();
      Render();
      window_.statusBar()->showMessage(QString::fromStdString("scene loaded from " + path));
    } catch (const Error& e) {
      Fail(e.what());
    }
  }

  void OpenPlan(const std::string& path) {
    try {
      auto file = std::make_unique<planners::PlanFile>(planners::ReadPlanFile(path));
      TROCAR_THROW_UNLESS(!file->plans.empty(), path << ": holds no plans");
      TROCAR_THROW_UNLESS(scene_->patient(), path << ": no patient is shown to put the plan on");
      const std::string patient_mismatch =
          planners::PatientModelMismatch(*file, *scene_->patient(), scene_->patient()->case_dir);
      TROCAR_THROW_UNLESS(patient_mismatch.empty(), path << ": " << patient_mismatch);
      TROCAR_THROW_UNLESS(scene_->robot(), path << ": no robot is shown to put the plan on");
      const std::string robot_mismatch = planners::RobotFileMismatch(*file);
      TROCAR_THROW_UNLESS(robot_mismatch.empty(), path << ": " << robot_mismatch);
      plan_ = std::move(file);
      FillPlans();
      SelectPlan(0);
    } catch (const Error& e) {
      Fail(e.what());  // the plan shown before stays
    }
  }

  QWidget* BuildStructuresTab() {
    auto* w = new QWidget;
    auto* form = new QFormLayout(w);
    for (const std::string& g : scene_->groups()) {
      auto* row = new QWidget;
      auto* h = new QHBoxLayout(row);
      h->setContentsMargins(0, 0, 0, 0);
      auto* show = new QCheckBox;
      show->setChecked(scene_->style().Visible(g));
      auto* opacity = new QSlider(Qt::Horizontal);
      opacity->setRange(0, 100);
      opacity->setValue(static_cast<int>(std::lround(100 * scene_->style().Opacity(g))));
      h->addWidget(show);
      h->addWidget(opacity, 1);
      form->addRow(QString::fromStdString(g), row);
      QObject::connect(show, &QCheckBox::toggled, [this, g](bool on) {
        scene_->SetVisible(g, on);
        Render();
      });
      QObject::connect(opacity, &QSlider::valueChanged, [this, g](int v) {
        scene_->SetOpacity(g, v / 100.0);
        Render();
      });
    }
    return w;
  }

  QWidget* BuildRobotTab() {
    auto* scroll = new QScrollArea;
    auto* w = new QWidget;
    auto* form = new QFormLayout(w);
    const robot::RobotModel* robot = scene_->robot();
    if (!robot) {
      form->addRow(new QLabel("No robot: open a plan, or trocar view CASE --robot FILE"));
      scroll->setWidget(w);
      return scroll;
    }
    position_ = new QLineEdit;
    rotation_ = new QLineEdit;
    rotation_->setToolTip("XYZ Euler angles (3 numbers, deg), a quaternion (w x y z) or a "
                          "rotation matrix (9 numbers, by rows)");
    auto* apply = new QPushButton("Move the base");
    form->addRow("base position (m)", position_);
    form->addRow("base rotation", rotation_);
    form->addRow(apply);
    QObject::connect(apply, &QPushButton::clicked, [this] {
      try {
        robot::RobotState state = *scene_->robot_state();
        state.X_WB = ParseBasePose(position_->text().toStdString(), rotation_->text().toStdString());
        kinematics::ForwardKinematics(*scene_->robot(), &state);
        scene_->SetRobotState(state);
        ShowCollisions();
        UpdateScope();
        Render();
      } catch (const Error& e) {
        Fail(e.what());
      }
    });
    for (int j = 0; j < robot->num_joints(); ++j) {
      const robot::Joint& joint = robot->joint(j);
      if (joint.q_index < 0) continue;
      auto* slider = new QSlider(Qt::Horizontal);
      slider->setRange(0, 1000);
      slider->setObjectName(QString::fromStdString(joint.name));
      form->addRow(QString::fromStdString(joint.name), slider);
      joint_sliders_.push_back({j, slider});
      QObject::connect(slider, &QSlider::valueChanged, [this, j](int v) {
        if (!syncing_) MoveJoint(j, v);
      });
    }
    scroll->setWidget(w);
    scroll->setWidgetResizable(true);
    SyncJoints();
    return scroll;
  }

  void MoveJoint(int j, int slider_value) {
    const robot::RobotModel& robot = *scene_->robot();
    const robot::Joint& joint = robot.joint(j);
    robot::RobotState state = *scene_->robot_state();
    Eigen::VectorXd q = state.q;
    const auto [lower, upper] = SliderRange(joint);
    q[joint.q_index] = lower + (upper - lower) * slider_value / 1000.0;
    const auto fk = kinematics::ForwardKinematics(robot, q, &state);
    if (!fk.ok()) {
      window_.statusBar()->showMessage(QString::fromStdString(joint.name + ": " + fk.message));
      return;
    }
    scene_->SetRobotState(state);
    ShowCollisions();
    window_.statusBar()->showMessage(
        QString::fromStdString(joint.name) + " = " +
        (joint.type == robot::JointType::kPrismatic ? Fixed(q[joint.q_index] * 1000, 1) + " mm"
                                                   : Fixed(q[joint.q_index] * 180 / M_PI, 1) + "°") +
        ": " + (pose_label_ ? pose_label_->text() : QString()));
    UpdateScope();
    Render();
  }

  void SyncJoints() {
    const robot::RobotState* state = scene_->robot_state();
    if (!state || !position_) return;
    syncing_ = true;
    for (const auto& [j, slider] : joint_sliders_) {
      const robot::Joint& joint = scene_->robot()->joint(j);
      const auto [lower, upper] = SliderRange(joint);
      const double v = upper > lower ? (state->q[joint.q_index] - lower) / (upper - lower) : 0.5;
      slider->setValue(static_cast<int>(std::lround(1000 * std::clamp(v, 0.0, 1.0))));
    }
    const Eigen::Vector3d p = state->X_WB.translation();
    position_->setText(Fixed(p.x(), 4) + ", " + Fixed(p.y(), 4) + ", " + Fixed(p.z(), 4));
    const Eigen::Vector3d e = EulerXyzDeg(state->X_WB.linear());
    rotation_->setText(Fixed(e.x(), 3) + ", " + Fixed(e.y(), 3) + ", " + Fixed(e.z(), 3));
    syncing_ = false;
  }

  QWidget* BuildViewTab() {
    auto* w = new QWidget;
    auto* form = new QFormLayout(w);
    auto* layout = new QComboBox;
    layout->addItems({"side by side", "external only", "camera only"});
    form->addRow("layout", layout);
    QObject::connect(layout, QOverload<int>::of(&QComboBox::currentIndexChanged), [this](int i) {
      Layout(i);
      Render();
    });
    camera_ = new QComboBox;
    camera_->addItem("endoscope (the plan's scope)");
    if (const robot::RobotModel* robot = scene_->robot()) {
      for (const auto& f : robot->frames()) camera_->addItem(QString::fromStdString(f.name));
    }
    form->addRow("camera on", camera_);
    QObject::connect(camera_, QOverload<int>::of(&QComboBox::currentIndexChanged), [this](int) {
      UpdateScope();
      Render();
    });
    auto* light = new QSlider(Qt::Horizontal);
    light->setRange(0, 300);
    light->setValue(100);
    form->addRow("scope light", light);
    QObject::connect(light, &QSlider::valueChanged, [this](int v) {
      light_ = v / 100.0;
      UpdateScope();
      Render();
    });
    auto* reset = new QPushButton("Frame the scene");
    form->addRow(reset);
    QObject::connect(reset, &QPushButton::clicked, [this] {
      Scene::Apply(scene_->ExternalCamera(Aspect(external_)), external_);
      Render();
    });
    return w;
  }

  double Aspect(vtkRenderer* r) const {
    double vp[4];
    r->GetViewport(vp);
    const int* size = render_window_->GetSize();
    const double w = (vp[2] - vp[0]) * std::max(size[0], 1), h = (vp[3] - vp[1]) * std::max(size[1], 1);
    return h > 0 ? w / h : 1.0;
  }

  /// 0 side by side, 1 external only, 2 camera only; without a camera, external only.
  void Layout(int mode) {
    layout_ = mode;
    const int shown = scope_available_ ? mode : 1;
    external_->SetDraw(shown != 2);
    scope_->SetDraw(shown != 1);
    external_->SetViewport(0, 0, shown == 0 ? 0.5 : 1, 1);
    scope_->SetViewport(shown == 0 ? 0.5 : 0, 0, 1, 1);
  }

  /// The camera pane follows its frame (the plan's scope, or the frame chosen).
  void UpdateScope() {
    scope_available_ = false;
    Layout(layout_);
    if (!scene_->robot()) return;
    try {
      ViewSpec spec;
      const planners::StoredPlan* plan = plan_ ? &plan_->plans[plan_index_] : nullptr;
      if (camera_ && camera_->currentIndex() > 0) {
        spec.kind = ViewSpec::Kind::kFrame;
        spec.camera.frame = camera_->currentText().toStdString();
      } else {
        spec.kind = ViewSpec::Kind::kEndoscope;
        if (!plan || plan->views.empty()) return;
      }
      FrameCamera used;
      const CameraPose pose = ViewCamera(*scene_, spec, 1.0, plan, &used);
      used.light_intensity = light_;
      Scene::Apply(pose, scope_, &used);
      scene_->LeaveOutCarrier(scope_, used, pose);
      scope_available_ = true;
      Layout(layout_);
    } catch (const Error& e) {
      Fail(e.what());
    }
  }

  std::unique_ptr<Scene> scene_;
  std::shared_ptr<const robot::RobotModel> robot_;
  WorkstationOptions options_;
  std::unique_ptr<planners::PlanCollisions> collisions_;
  QComboBox* motions_ = nullptr;
  QSlider* frame_slider_ = nullptr;
  QLabel* pose_label_ = nullptr;
  QTimer* timer_ = nullptr;
  std::vector<std::size_t> motion_index_;
  const planners::StoredMotion* replayed_ = nullptr;  ///< the motion in frames_
  std::vector<ReplayFrame> frames_;
  std::unique_ptr<planners::PlanFile> plan_;
  std::size_t plan_index_ = 0;
  QMainWindow window_;
  QVTKOpenGLNativeWidget* vtk_widget_ = nullptr;
  vtkSmartPointer<vtkGenericOpenGLRenderWindow> render_window_;
  vtkNew<vtkRenderer> external_, scope_, marker_;
  QListWidget* plans_ = nullptr;
  QTextBrowser* details_ = nullptr;
  QLineEdit* surgeon_ = nullptr;
  QLineEdit* override_ = nullptr;
  QPushButton* approve_ = nullptr;
  QLineEdit* note_ = nullptr;
  QLineEdit* position_ = nullptr;
  QLineEdit* rotation_ = nullptr;
  QComboBox* camera_ = nullptr;
  std::vector<std::pair<int, QSlider*>> joint_sliders_;
  bool syncing_ = false, filling_ = false;
  int layout_ = 0;
  bool scope_available_ = false;
  double light_ = 1.0;
  int code_ = 0;
};

}  // namespace

vtkInteractorStyle* NewThesisCameraStyle() { return ThesisCameraStyle::New(); }

int RunWorkstation(std::unique_ptr<Scene> scene, std::shared_ptr<const robot::RobotModel> robot,
                   const planners::PlanFile* plan, const WorkstationOptions& options) {
  const char* display = std::getenv("DISPLAY");
  TROCAR_THROW_UNLESS(display && *display,
                      "the workstation window needs an X display (DISPLAY is not set); for "
                      "pictures without one: trocar view ... --screenshot FILE.png under xvfb-run");
  QSurfaceFormat::setDefaultFormat(QVTKOpenGLNativeWidget::defaultFormat());
  static int argc = 1;
  static char name[] = "trocar";
  static char* argv[] = {name, nullptr};
  QApplication app(argc, argv);
  Workstation station(std::move(scene), std::move(robot), plan, options);
  return station.Run(app);
}

std::string PlanPageHtml(const planners::PlanFile& file, std::size_t index) {
  TROCAR_THROW_UNLESS(index < file.plans.size(), file.path << ": plan " << index + 1 << ": the file holds "
                                                           << file.plans.size() << " plans");
  return PlanHtml(file, index).toStdString();
}

}  // namespace trocar::viz
