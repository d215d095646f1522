#include "teleop_view.hpp"

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <thread>

#include <QApplication>
#include <QKeyEvent>
#include <QLabel>
#include <QMainWindow>
#include <QStatusBar>
#include <QSurfaceFormat>
#include <QTimer>
#include <QVTKOpenGLNativeWidget.h>
#include <vtkGenericOpenGLRenderWindow.h>
#include <vtkNew.h>
#include <vtkRenderWindowInteractor.h>
#include <vtkInteractorStyle.h>
#include <vtkRenderer.h>
#include <vtkTextActor.h>
#include <vtkTextProperty.h>

#include <unistd.h>

#include "common/error.hpp"
#include "kinematics/forward_kinematics.hpp"
#include "workstation.hpp"

namespace trocar::viz {

control::DeviceSample KeyboardInput::Sample(double t) {
  const double dt = std::clamp(t - last_t_, 0.0, 0.1);
  last_t_ = t;
  X_DH_.translation() += speed_ * dt * Eigen::Vector3d(vx_.load(), vy_.load(), vz_.load());
  X_DH_.linear() = X_DH_.linear() * Eigen::AngleAxisd(0.5 * dt * roll_.load(), Eigen::Vector3d::UnitZ());
  control::DeviceSample s;
  s.t = t;
  s.X_DH = X_DH_;
  s.clutch = clutch_.load();
  return s;
}

void KeyboardInput::Press(int key, bool down) {
  const int v = down ? 1 : 0;
  switch (key) {
    case Qt::Key_Right: vx_ = v; break;
    case Qt::Key_Left: vx_ = -v; break;
    case Qt::Key_Up: vy_ = v; break;
    case Qt::Key_Down: vy_ = -v; break;
    case Qt::Key_PageUp: vz_ = v; break;
    case Qt::Key_PageDown: vz_ = -v; break;
    case Qt::Key_Q: roll_ = v; break;
    case Qt::Key_E: roll_ = -v; break;
    case Qt::Key_Space: clutch_ = down; break;
    default: break;
  }
}

namespace {

/// Passes the window's key presses and releases to the keyboard device.
class KeyFilter : public QObject {
 public:
  explicit KeyFilter(KeyboardInput* keyboard) : keyboard_(keyboard) {}
  bool eventFilter(QObject* object, QEvent* event) override {
    if ((event->type() == QEvent::KeyPress || event->type() == QEvent::KeyRelease) && keyboard_) {
      auto* key = static_cast<QKeyEvent*>(event);
      if (!key->isAutoRepeat()) keyboard_->Press(key->key(), event->type() == QEvent::KeyPress);
      return true;
    }
    return QObject::eventFilter(object, event);
  }

 private:
  KeyboardInput* keyboard_;
};

}  // namespace

TeleopViewStats RunTeleopView(Scene* scene, control::TripleBuffer<control::SessionSnapshot>* snapshots,
                              const std::function<bool()>& finished, const TeleopViewOptions& options,
                              KeyboardInput* keyboard) {
  const char* display = std::getenv("DISPLAY");
  TROCAR_THROW_UNLESS(display && *display,
                      "the teleoperation view needs an X display (DISPLAY is not set): run under "
                      "xvfb-run, or without the view");
  TROCAR_OPTION_UNLESS(options.fps >= 1 && options.fps <= 240, "fps",
                       options.fps << ", expected 1..240");
  TROCAR_THROW_UNLESS(scene->robot(), "the teleoperation view: the scene has no robot");
  // Mesa's software rasteriser (Xvfb, no GPU) draws on as many threads as there are cores, and
  // then takes the control thread's core: measured on 2 cores, the control loop kept 94 % of its
  // headless rate with it, 99 % with one render thread. Leave the control thread a core.
  if (!std::getenv("LP_NUM_THREADS")) {
    const unsigned cores = std::max(1u, std::thread::hardware_concurrency());
    ::setenv("LP_NUM_THREADS", std::to_string(std::max(1u, cores - 1)).c_str(), 0);
  }
  QSurfaceFormat::setDefaultFormat(QVTKOpenGLNativeWidget::defaultFormat());
  static int argc = 1;
  static char name[] = "trocar";
  static char* argv[] = {name, nullptr};
  QApplication app(argc, argv);
  QMainWindow window;
  window.setWindowTitle("trocar teleop");
  window.resize(options.width, options.height);
  auto* widget = new QVTKOpenGLNativeWidget;
  vtkNew<vtkGenericOpenGLRenderWindow> render_window;
  widget->setRenderWindow(render_window);
  AdaptAfterFirstFrame(render_window);  // multisampling off under software rendering
  vtkNew<vtkRenderer> renderer;
  scene->AddTo(renderer);
  render_window->AddRenderer(renderer);
  // The endoscope's view on the right half, when asked for: the same actors (the pointer too).
  vtkNew<vtkRenderer> scope;
  if (options.endoscope) {
    renderer->SetViewport(0, 0, 0.5, 1);
    scope->SetViewport(0.5, 0, 1, 1);
    scene->AddTo(scope);
    render_window->AddRenderer(scope);
    scope->SetInteractive(0);
  }
  vtkInteractorStyle* style = NewThesisCameraStyle();
  render_window->GetInteractor()->SetInteractorStyle(style);
  style->Delete();
  window.setCentralWidget(widget);
  auto* status = new QLabel;
  window.statusBar()->addWidget(status, 1);
  // The devices' overlay: top left of the 3D view, over the scene.
  vtkNew<vtkTextActor> overlay;
  overlay->GetTextProperty()->SetFontSize(14);
  overlay->GetTextProperty()->SetColor(1.0, 1.0, 0.85);
  overlay->SetDisplayPosition(8, 8);
  if (options.overlay) renderer->AddViewProp(overlay);
  KeyFilter filter(keyboard);
  app.installEventFilter(&filter);
  const double aspect = double(options.width) / options.height / (options.endoscope ? 2.0 : 1.0);
  Scene::Apply(scene->ExternalCamera(aspect), renderer);

  // The render side's own kinematics state: the control thread's is never touched.
  const robot::RobotModel& robot = *scene->robot();
  robot::RobotState state = *scene->robot_state();
  TeleopViewStats stats;
  control::SessionSnapshot snap;
  const auto t0 = std::chrono::steady_clock::now();
  QTimer timer;
  timer.setInterval(static_cast<int>(1000.0 / options.fps));
  int code = 0;
  QObject::connect(&timer, &QTimer::timeout, [&] {
    if (snapshots->Read(&snap)) {
      ++stats.snapshots;
      std::string extra;
      if (snap.q.size() == robot.num_positions() && kinematics::ForwardKinematics(robot, snap.q, &state).ok()) {
        scene->SetRobotState(state);
        if (options.on_frame) extra = options.on_frame(state);
        if (options.endoscope) {
          const CameraPose pose = scene->OnFrame(*options.endoscope);
          Scene::Apply(pose, scope, &*options.endoscope);
          scene->LeaveOutCarrier(scope, *options.endoscope, pose);
        }
      }
      if (options.pointer_channel >= 0 && options.pointer_channel < static_cast<int>(snap.channels.size()))
        scene->SetPointer(snap.channels[options.pointer_channel].X_WD);
      status->setText(QString("t = %1 s").arg(snap.t, 0, 'f', 2) +
                      (snap.status == control::SampleStatus::kFollowing ? "" : " (holding)") +
                      (extra.empty() ? QString() : "  ·  " + QString::fromStdString(extra)));
    }
    if (options.overlay) overlay->SetInput(options.overlay().c_str());
    render_window->Render();
    ++stats.frames;
    if (finished()) {
      timer.stop();
      if (!options.grab_path.empty()) {
        const QImage image = window.grab().toImage();
        const std::string tmp = options.grab_path + ".tmp" + std::to_string(::getpid()) + ".png";
        std::error_code ec;
        if (!image.save(QString::fromStdString(tmp), "PNG")) {
          std::cerr << "error: " << options.grab_path << ": cannot write the window's image\n";
          code = 1;
        } else {
          std::filesystem::rename(tmp, options.grab_path, ec);
          if (ec) code = 1;
        }
      }
      app.quit();
    }
  });
  window.show();
  timer.start();
  app.exec();
  stats.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  TROCAR_THROW_UNLESS(code == 0, options.grab_path << ": cannot write the window's image");
  return stats;
}

}  // namespace trocar::viz
