#include "scene.hpp"

#include <unistd.h>
#include <vtkActor.h>
#include <vtkAppendPolyData.h>
#include <vtkArrowSource.h>
#include <vtkBillboardTextActor3D.h>
#include <vtkCamera.h>
#include <vtkCellArray.h>
#include <vtkCommand.h>
#include <vtkConeSource.h>
#include <vtkCubeSource.h>
#include <vtkCylinderSource.h>
#include <vtkFollower.h>
#include <vtkImageData.h>
#include <vtkLegendBoxActor.h>
#include <vtkLight.h>
#include <vtkMatrix4x4.h>
#include <vtkNew.h>
#include <vtkPlaneSource.h>
#include <vtkPoints.h>
#include <vtkPolyData.h>
#include <vtkPolyDataMapper.h>
#include <vtkPolyDataNormals.h>
#include <vtkPolyLine.h>
#include <vtkProperty.h>
#include <vtkQuadricDecimation.h>
#include <vtkRenderWindow.h>
#include <vtkRenderer.h>
#include <vtkSmartPointer.h>
#include <vtkSphereSource.h>
#include <vtkTextProperty.h>
#include <vtkTransform.h>
#include <vtkTransformPolyDataFilter.h>
#include <vtkTubeFilter.h>
#include <vtkVectorText.h>
#include <vtkWeakPointer.h>
#include <vtkWindowToImageFilter.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <sstream>

#include "collision/triangle_bvh.hpp"
#include "common/error.hpp"
#include "common/file_util.hpp"
#include "kinematics/appearance.hpp"
#include "kinematics/forward_kinematics.hpp"
#include "plan/reachability.hpp"

namespace trocar::viz {
namespace {

constexpr double kPi = 3.14159265358979323846;

vtkSmartPointer<vtkMatrix4x4> ToVtk(const Eigen::Isometry3d& X) {
  auto m = vtkSmartPointer<vtkMatrix4x4>::New();
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) m->SetElement(r, c, X.matrix()(r, c));
  return m;
}

/// A triangle mesh (scaled) as VTK polygons with smooth normals.
vtkSmartPointer<vtkPolyData> ToPolyData(const TriangleMesh& mesh,
                                        const Eigen::Vector3d& scale = Eigen::Vector3d::Ones()) {
  vtkNew<vtkPoints> points;
  points->SetDataTypeToDouble();
  points->SetNumberOfPoints(static_cast<vtkIdType>(mesh.vertices.size()));
  for (std::size_t i = 0; i < mesh.vertices.size(); ++i) {
    const Eigen::Vector3d p = mesh.vertices[i].cwiseProduct(scale);
    points->SetPoint(static_cast<vtkIdType>(i), p.data());
  }
  vtkNew<vtkCellArray> cells;
  const auto n = static_cast<vtkIdType>(mesh.vertices.size());
  for (const Eigen::Vector3i& t : mesh.triangles) {
    if (t.minCoeff() < 0 || t.maxCoeff() >= n) continue;  // a validated mesh has none
    const vtkIdType ids[3] = {t[0], t[1], t[2]};
    cells->InsertNextCell(3, ids);
  }
  vtkNew<vtkPolyData> poly;
  poly->SetPoints(points);
  poly->SetPolys(cells);
  vtkNew<vtkPolyDataNormals> normals;
  normals->SetInputData(poly);
  normals->SetFeatureAngle(60);
  normals->ConsistencyOn();
  normals->Update();
  vtkSmartPointer<vtkPolyData> out = normals->GetOutput();
  return out;
}

vtkSmartPointer<vtkPolyData> Output(vtkPolyDataAlgorithm* algorithm) {
  algorithm->Update();
  vtkSmartPointer<vtkPolyData> out = algorithm->GetOutput();
  return out;
}

/// A cylinder of `radius` and `length` along z, centred on the origin (VTK's is along y).
vtkSmartPointer<vtkPolyData> CylinderZ(double radius, double length, bool caps) {
  vtkNew<vtkCylinderSource> cylinder;
  cylinder->SetRadius(radius);
  cylinder->SetHeight(length);
  cylinder->SetResolution(16);
  cylinder->SetCapping(caps);
  vtkNew<vtkTransform> turn;
  turn->RotateX(90);
  vtkNew<vtkTransformPolyDataFilter> filter;
  filter->SetTransform(turn);
  filter->SetInputConnection(cylinder->GetOutputPort());
  return Output(filter);
}

vtkSmartPointer<vtkPolyData> Sphere(const Eigen::Vector3d& centre, double radius, int resolution = 16) {
  vtkNew<vtkSphereSource> sphere;
  sphere->SetCenter(centre.data());
  sphere->SetRadius(radius);
  sphere->SetThetaResolution(resolution);
  sphere->SetPhiResolution(resolution);
  return Output(sphere);
}

vtkSmartPointer<vtkPolyData> ShapePolyData(const robot::Geometry& g) {
  using Shape = robot::Geometry::Shape;
  switch (g.shape) {
    case Shape::kMesh:
      if (!g.mesh) return nullptr;
      return ToPolyData(*g.mesh, g.mesh_scale);
    case Shape::kBox: {
      vtkNew<vtkCubeSource> box;
      box->SetXLength(g.size.x());
      box->SetYLength(g.size.y());
      box->SetZLength(g.size.z());
      return Output(box);
    }
    case Shape::kCylinder:
      return CylinderZ(g.size.x(), g.size.y(), true);
    case Shape::kSphere:
      return Sphere(Eigen::Vector3d::Zero(), g.size.x());
    case Shape::kCapsule: {
      vtkNew<vtkAppendPolyData> append;
      append->AddInputData(CylinderZ(g.size.x(), g.size.y(), false));
      append->AddInputData(Sphere(Eigen::Vector3d(0, 0, g.size.y() / 2), g.size.x(), 12));
      append->AddInputData(Sphere(Eigen::Vector3d(0, 0, -g.size.y() / 2), g.size.x(), 12));
      return Output(append);
    }
  }
  return nullptr;
}

/// A polyline thickened into a tube.
// The colours of the second, third, ... target (the first takes the style's "target"): apart from
// each other, from the heart's red and from the skin, bones, cones and candidates.
const std::array<Eigen::Vector3d, 4> kTargetPalette = {
    Eigen::Vector3d(1.00, 0.42, 0.78), Eigen::Vector3d(0.00, 0.60, 0.55),
    Eigen::Vector3d(0.55, 0.35, 0.10), Eigen::Vector3d(0.85, 0.90, 1.00)};

// The part of a polyline (points with their arc lengths from the first) between arc lengths a
// and b, its ends interpolated.
std::vector<Eigen::Vector3d> SubCurve(const std::vector<Eigen::Vector3d>& points,
                                      const std::vector<double>& arc, double a, double b) {
  std::vector<Eigen::Vector3d> out;
  auto at = [&](double t) {
    std::size_t i = 1;
    while (i + 1 < points.size() && arc[i] < t) ++i;
    const double len = arc[i] - arc[i - 1];
    const double u = len > 0 ? std::clamp((t - arc[i - 1]) / len, 0.0, 1.0) : 0.0;
    return Eigen::Vector3d(points[i - 1] + u * (points[i] - points[i - 1]));
  };
  if (points.size() < 2 || b <= a) return out;
  out.push_back(at(a));
  for (std::size_t i = 0; i < points.size(); ++i)
    if (arc[i] > a && arc[i] < b) out.push_back(points[i]);
  out.push_back(at(b));
  return out;
}

vtkSmartPointer<vtkPolyData> Tube(const std::vector<Eigen::Vector3d>& points, double radius) {
  if (points.size() < 2) return nullptr;
  vtkNew<vtkPoints> p;
  p->SetDataTypeToDouble();
  vtkNew<vtkPolyLine> line;
  line->GetPointIds()->SetNumberOfIds(static_cast<vtkIdType>(points.size()));
  for (std::size_t i = 0; i < points.size(); ++i) {
    p->InsertNextPoint(points[i].data());
    line->GetPointIds()->SetId(static_cast<vtkIdType>(i), static_cast<vtkIdType>(i));
  }
  vtkNew<vtkCellArray> lines;
  lines->InsertNextCell(line);
  vtkNew<vtkPolyData> poly;
  poly->SetPoints(p);
  poly->SetLines(lines);
  vtkNew<vtkTubeFilter> tube;
  tube->SetInputData(poly);
  tube->SetRadius(radius);
  tube->SetNumberOfSides(10);
  tube->CappingOn();
  return Output(tube);
}

/// Approach cones: apex at each point, opening along its normal (the instrument's side).
vtkSmartPointer<vtkPolyData> Cones(const std::vector<Eigen::Vector3d>& points,
                                   const std::vector<Eigen::Vector3d>& normals, double height,
                                   double half_angle) {
  vtkNew<vtkAppendPolyData> append;
  int added = 0;
  for (std::size_t i = 0; i < points.size() && i < normals.size(); ++i) {
    if (!normals[i].allFinite() || normals[i].norm() < 1e-9) continue;
    const Eigen::Vector3d n = normals[i].normalized();
    vtkNew<vtkConeSource> cone;
    const Eigen::Vector3d centre = points[i] + n * height / 2;
    const Eigen::Vector3d direction = -n;
    cone->SetCenter(centre.data());
    cone->SetDirection(direction.data());
    cone->SetHeight(height);
    cone->SetRadius(height * std::tan(half_angle));
    cone->SetResolution(20);
    cone->CappingOff();
    append->AddInputData(Output(cone));
    ++added;
  }
  if (added == 0) return nullptr;
  return Output(append);
}

std::vector<Eigen::Vector3d> ToWorld(const std::vector<Eigen::Vector3d>& points_P,
                                     const Eigen::Isometry3d& X_WP) {
  std::vector<Eigen::Vector3d> out;
  out.reserve(points_P.size());
  for (const auto& p : points_P) out.push_back(X_WP * p);
  return out;
}

}  // namespace

struct Scene::Impl {
  std::shared_ptr<const patient::PatientModel> patient;
  std::shared_ptr<const robot::RobotModel> robot;
  SceneStyle style;
  std::unique_ptr<robot::RobotState> state;

  struct Group {
    std::string name;
    std::vector<vtkSmartPointer<vtkActor>> actors;
  };
  std::vector<Group> groups;
  struct LinkActor {
    int link = -1;
    Eigen::Isometry3d X_LG = Eigen::Isometry3d::Identity();
    vtkSmartPointer<vtkActor> actor;
    const robot::Geometry* geometry = nullptr;  ///< in the robot model (shared, immutable)
  };
  std::vector<LinkActor> links;
  /// The meshes the robot's links wear, and why some do not (LinkActor::geometry points here).
  kinematics::Dressing dressing;
  /// The skin's hierarchy, built when the external camera first looks for a clear direction.
  mutable std::unique_ptr<collision::TriangleBvh> skin_bvh;
  std::vector<int> highlighted, near;
  bool pointer_shown = false;
  /// Text beside what it names, facing the camera (issue #43 item 2): each target's name at its
  /// middle, each port's arm and space. Shown with the "labels" overlay and its owner group.
  /// Each renderer has its own copy of a label's actor: a billboard shared by two views (side by
  /// side) took the other view's turn.
  struct Label {
    std::string owner;  ///< the group it names ("target:LAD", "ports")
    std::string text;
    Eigen::Vector3d p_W = Eigen::Vector3d::Zero();
    std::vector<std::pair<vtkWeakPointer<vtkRenderer>, vtkSmartPointer<vtkBillboardTextActor3D>>>
        copies;
  };
  std::vector<Label> labels;
  /// The renderers the scene was added to, so that a label made later (a plan's ports) joins
  /// them.
  std::vector<vtkWeakPointer<vtkRenderer>> renderers;

  bool LabelsShown() const {
    if (!style.flat) return style.Visible("labels");
    const auto it = style.visible.find("labels");
    return it != style.visible.end() && it->second;
  }
  vtkSmartPointer<vtkBillboardTextActor3D> LabelActor(const Label& l) const {
    auto actor = vtkSmartPointer<vtkBillboardTextActor3D>::New();
    actor->SetInput(l.text.c_str());
    actor->SetPosition(l.p_W.x(), l.p_W.y(), l.p_W.z());
    actor->SetDisplayOffset(8, 8);
    vtkTextProperty* t = actor->GetTextProperty();
    t->SetFontSize(15);
    t->BoldOn();
    const Eigen::Vector3d c = style.Colour(l.owner);
    t->SetColor(c.data());
    t->SetBackgroundColor(0.05, 0.05, 0.07);
    t->SetBackgroundOpacity(0.6);
    actor->SetVisibility(LabelsShown() && style.Visible(l.owner));
    return actor;
  }
  void AddLabel(const std::string& owner, const std::string& text, const Eigen::Vector3d& p_W) {
    labels.push_back({owner, text, p_W, {}});
    AddLabelsToRenderers();
  }
  void StyleLabels() {
    for (const Label& l : labels)
      for (const auto& [r, actor] : l.copies)
        actor->SetVisibility(LabelsShown() && style.Visible(l.owner));
  }
  void RemoveLabels(const std::string& owner) {
    for (const Label& l : labels) {
      if (l.owner != owner) continue;
      for (const auto& [r, actor] : l.copies)
        if (r) r->RemoveViewProp(actor);
    }
    labels.erase(std::remove_if(labels.begin(), labels.end(),
                                [&](const Label& l) { return l.owner == owner; }),
                 labels.end());
  }
  void AddLabelsToRenderers() {
    renderers.erase(
        std::remove_if(renderers.begin(), renderers.end(), [](const auto& r) { return !r; }),
        renderers.end());
    for (Label& l : labels) {
      l.copies.erase(
          std::remove_if(l.copies.begin(), l.copies.end(), [](const auto& c) { return !c.first; }),
          l.copies.end());
      for (auto& r : renderers) {
        const bool has = std::any_of(l.copies.begin(), l.copies.end(), [&](const auto& c) {
          return c.first.GetPointer() == r.GetPointer();
        });
        if (has) continue;
        auto actor = LabelActor(l);
        r->AddViewProp(actor);
        l.copies.push_back({r, actor});
      }
    }
  }

  Group& GetGroup(const std::string& name) {
    for (Group& g : groups)
      if (g.name == name) return g;
    groups.push_back({name, {}});
    return groups.back();
  }
  const Group* FindGroup(const std::string& name) const {
    for (const Group& g : groups)
      if (g.name == name) return &g;
    return nullptr;
  }
  Group* FindGroup(const std::string& name) {
    for (Group& g : groups)
      if (g.name == name) return &g;
    return nullptr;
  }

  vtkSmartPointer<vtkActor> Add(const std::string& group, vtkSmartPointer<vtkPolyData> poly,
                                const Eigen::Isometry3d& X_W = Eigen::Isometry3d::Identity()) {
    Group& g = GetGroup(group);  // a group exists even when it draws nothing
    if (!poly || poly->GetNumberOfCells() == 0) return nullptr;
    vtkNew<vtkPolyDataMapper> mapper;
    mapper->SetInputData(poly);
    mapper->ScalarVisibilityOff();
    auto actor = vtkSmartPointer<vtkActor>::New();
    actor->SetMapper(mapper);
    actor->SetUserMatrix(ToVtk(X_W));
    g.actors.push_back(actor);
    ApplyStyle(g);
    return actor;
  }

  void ApplyStyle(const Group& g) {
    const bool is_robot = g.name == "robot";
    for (const auto& actor : g.actors) {
      Eigen::Vector3d colour = style.Colour(g.name);
      if (is_robot) {
        for (const LinkActor& la : links) {
          if (la.actor != actor) continue;
          if (std::find(highlighted.begin(), highlighted.end(), la.link) != highlighted.end()) {
            colour = style.Colour("collision");
          } else if (std::find(near.begin(), near.end(), la.link) != near.end()) {
            colour = style.Colour("near_miss");
          }
        }
      }
      vtkProperty* p = actor->GetProperty();
      p->SetColor(colour.data());
      p->SetOpacity(style.Opacity(g.name));
      actor->SetVisibility(style.Visible(g.name) && (g.name != "pointer" || pointer_shown));
      // Closed surfaces are seen from outside only: a camera inside one (the endoscope in the
      // chest, a scope tip at a port) looks through it.
      p->SetBackfaceCulling(g.name == "skin" || g.name == "ports" || g.name == "pivots");
      if (style.flat) {
        p->LightingOff();
        p->SetAmbient(1.0);
        p->SetDiffuse(0.0);
        p->SetSpecular(0.0);
      } else {
        p->LightingOn();
        p->SetAmbient(0.12);
        p->SetDiffuse(0.85);
        p->SetSpecular(g.name == "skin" ? 0.05 : 0.25);
        p->SetSpecularPower(20);
      }
    }
  }

  void BuildPatient() {
    const patient::PatientModel& m = *patient;
    // Display decimation: the surfaces together within the style's triangle budget, each
    // reduced by the same share (the model itself is untouched; collisions use it whole).
    long total = 0;
    for (const patient::Structure& s : m.structures) total += static_cast<long>(s.mesh.triangles.size());
    const double keep = style.patient_triangles > 0 && total > style.patient_triangles
                            ? static_cast<double>(style.patient_triangles) / total
                            : 1.0;
    for (const patient::Structure& s : m.structures) {
      vtkSmartPointer<vtkPolyData> poly = ToPolyData(s.mesh);
      if (keep < 1.0 && poly->GetNumberOfPolys() > 200) {
        vtkNew<vtkQuadricDecimation> decimate;
        decimate->SetInputData(poly);
        decimate->SetTargetReduction(1.0 - keep);
        decimate->VolumePreservationOn();
        decimate->Update();
        vtkNew<vtkPolyDataNormals> normals;
        normals->SetInputConnection(decimate->GetOutputPort());
        normals->SetFeatureAngle(60);
        poly = Output(normals);
      }
      Add(s.name, poly, m.X_WP);
    }
    // Each target its own colour (issue #43 item 2): the style's for "target:NAME" when it
    // names one, else the first target takes the targets' colour and the others the palette's.
    for (std::size_t i = 0; i < m.targets.size(); ++i) {
      const std::string group = "target:" + m.targets[i].name;
      if (!style.colours.count(group))
        style.colours[group] =
            i == 0 ? style.Colour("target") : kTargetPalette[(i - 1) % kTargetPalette.size()];
      Add(group, Tube(ToWorld(m.targets[i].points, m.X_WP), 0.0015));
      if (!m.targets[i].points.empty())
        AddLabel(group, m.targets[i].name,
                 m.X_WP * m.targets[i].points[m.targets[i].points.size() / 2]);
    }
    {
      vtkNew<vtkAppendPolyData> append;
      int n = 0;
      for (const patient::PortCandidate& c : m.port_candidates) {
        if (auto tube = Tube(ToWorld(c.skin, m.X_WP), 0.0012)) {
          append->AddInputData(tube);
          ++n;
        }
      }
      Add("candidates", n ? Output(append) : nullptr);
    }
    ShowModelCones();
    GetGroup("ports");
    GetGroup("pivots");
    // The table (its top at `height`, long axis along x_W) and the floor (z = 0).
    vtkNew<vtkCubeSource> table;
    table->SetXLength(m.table.length);
    table->SetYLength(m.table.width);
    table->SetZLength(m.table.thickness);
    table->SetCenter(0, 0, m.table.height - m.table.thickness / 2);
    Add("table", Output(table));
    BuildFloor();
  }

  void BuildFloor() {
    vtkNew<vtkCubeSource> floor;
    floor->SetXLength(5.0);
    floor->SetYLength(5.0);
    floor->SetZLength(0.002);
    floor->SetCenter(0, 0, -0.001);
    Add("floor", Output(floor));
  }

  /// Cones from the model's targets: at most 8 per target, evenly along it.
  void ShowModelCones() {
    std::vector<Eigen::Vector3d> points, normals;
    if (!patient) return;
    for (const patient::Target& t : patient->targets) {
      const std::size_t n = std::min(t.points.size(), t.normals.size());
      const std::size_t step = std::max<std::size_t>(1, (n + 7) / 8);
      for (std::size_t i = 0; i < n; i += step) {
        points.push_back(patient->X_WP * t.points[i]);
        normals.push_back(patient->X_WP.linear() * t.normals[i]);
      }
    }
    ReplaceGroup("cones", Cones(points, normals, 0.02, 30 * kPi / 180));
  }

  void ReplaceGroup(const std::string& name, vtkSmartPointer<vtkPolyData> poly) {
    Group& g = GetGroup(name);
    for (auto& a : g.actors) {
      if (a) a->GetMapper()->RemoveAllInputConnections(0);
    }
    if (!g.actors.empty() && poly) {
      vtkPolyDataMapper::SafeDownCast(g.actors[0]->GetMapper())->SetInputData(poly);
      g.actors.resize(1);
      ApplyStyle(g);
      return;
    }
    if (!g.actors.empty()) {
      // Nothing to draw: keep the actor (a window may hold it) with an empty input.
      vtkPolyDataMapper::SafeDownCast(g.actors[0]->GetMapper())->SetInputData(vtkNew<vtkPolyData>());
      g.actors.resize(1);
      return;
    }
    Add(name, poly);
  }

  /// Swept spheres (segment, radius) around the robot's drawn shapes at its current pose: a
  /// capsule or cylinder its axis, a box its longest side with the other two's half-diagonal, a
  /// sphere its centre, a mesh its drawn bounds' diagonal.
  struct Swept {
    Eigen::Vector3d a, b;
    double radius;
  };
  std::vector<Swept> RobotSwept() const {
    std::vector<Swept> out;
    if (!robot || !state) return out;
    for (const LinkActor& la : links) {
      if (!la.geometry || la.link >= static_cast<int>(state->X_WL.size()) ||
          !la.actor->GetVisibility())
        continue;
      const Eigen::Isometry3d X_WG = state->X_WL[la.link] * la.X_LG;
      const robot::Geometry& g = *la.geometry;
      const Eigen::Vector3d s = g.size;
      switch (g.shape) {
        case robot::Geometry::Shape::kCapsule:
        case robot::Geometry::Shape::kCylinder:
          out.push_back({X_WG * Eigen::Vector3d(0, 0, -s.y() / 2),
                         X_WG * Eigen::Vector3d(0, 0, s.y() / 2), s.x()});
          break;
        case robot::Geometry::Shape::kSphere:
          out.push_back({X_WG.translation(), X_WG.translation(), s.x()});
          break;
        case robot::Geometry::Shape::kBox: {
          int k = 0;
          s.maxCoeff(&k);
          Eigen::Vector3d along = Eigen::Vector3d::Zero();
          along[k] = s[k] / 2;
          Eigen::Vector3d rest = s / 2;
          rest[k] = 0;
          out.push_back({X_WG * (-along), X_WG * along, rest.norm()});
          break;
        }
        default: {
          double b[6];
          la.actor->GetBounds(b);
          if (!(b[0] <= b[1])) break;
          const Eigen::Vector3d lo(b[0], b[2], b[4]), hi(b[1], b[3], b[5]);
          out.push_back({(lo + hi) / 2, (lo + hi) / 2, (hi - lo).norm() / 2});
        }
      }
    }
    return out;
  }

  /// The external camera's direction onto the chest: the default one (`horizontal` turned up by
  /// 45 degrees), unless the robot's arms or the body itself hide the ports from there; then, of
  /// the directions around the vertical (every 30 degrees, at 45 and 63 degrees of elevation,
  /// nearest the default first), the first that hides at most 2 % more of them than the least
  /// hidden. The points looked at: about 300 each of the ports' markers, the candidate curves and
  /// the skin. A point is hidden when the line from the camera to it passes through one of the
  /// robot's drawn shapes (RobotSwept), and a port's or a candidate's also when it passes through
  /// the skin short of its last centimetre (the ports seen from the other side of the body).
  Eigen::Vector3d LeastHiddenDirection(const Eigen::Vector3d& centre, double distance,
                                       const Eigen::Vector3d& horizontal) const {
    const Eigen::Vector3d h = Eigen::Vector3d(horizontal.x(), horizontal.y(), 0).normalized();
    const Eigen::Vector3d first = (h + Eigen::Vector3d::UnitZ()).normalized();
    const std::vector<Swept> shapes = RobotSwept();
    std::vector<Eigen::Vector3d> points;
    for (const char* name : {"ports", "candidates"}) {
      const Group* group = FindGroup(name);
      if (group) AddPoints(*group, &points);
    }
    const std::size_t on_ports = points.size();  // these may also be hidden by the body
    if (const Group* group = FindGroup("skin")) AddPoints(*group, &points);
    const patient::Structure* skin_structure = patient ? patient->Find("skin") : nullptr;
    if (!skin_bvh && skin_structure && !skin_structure->mesh.triangles.empty())
      skin_bvh = std::make_unique<collision::TriangleBvh>(skin_structure->mesh);
    if (points.empty() || (shapes.empty() && !skin_bvh)) return first;
    const Eigen::Isometry3d X_PW = patient ? patient->X_WP.inverse() : Eigen::Isometry3d::Identity();
    auto hidden = [&](const Eigen::Vector3d& direction) {
      const Eigen::Vector3d camera = centre + distance * direction;
      int n = 0;
      for (std::size_t i = 0; i < points.size(); ++i) {
        const Eigen::Vector3d& p = points[i];
        bool blocked = false;
        for (const Swept& s : shapes) {
          Eigen::Vector3d c1, c2;
          if (collision::SegmentSegmentClosest(camera, p, s.a, s.b, &c1, &c2) <
              s.radius * s.radius) {
            blocked = true;
            break;
          }
        }
        if (!blocked && skin_bvh && i < on_ports) {
          const Eigen::Vector3d to = p - camera;
          const double length = to.norm();
          if (length > 0.02) {
            const Eigen::Vector3d short_of = camera + to * ((length - 0.01) / length);
            blocked = skin_bvh->Closest(X_PW * camera, X_PW * short_of, 1e-9).found();
          }
        }
        n += blocked;
      }
      return static_cast<double>(n) / static_cast<double>(points.size());
    };
    std::vector<Eigen::Vector3d> candidates;
    for (int k : {0, 1, -1, 2, -2, 3, -3, 4, -4, 5, -5, 6}) {
      const double turn = k * kPi / 6;
      const Eigen::Vector3d turned(std::cos(turn) * h.x() - std::sin(turn) * h.y(),
                                   std::sin(turn) * h.x() + std::cos(turn) * h.y(), 0.0);
      for (double up : {1.0, 2.0}) candidates.push_back((turned + up * Eigen::Vector3d::UnitZ()).normalized());
    }
    std::vector<double> share;
    for (const auto& d : candidates) share.push_back(hidden(d));
    const double least = *std::min_element(share.begin(), share.end());
    for (std::size_t i = 0; i < candidates.size(); ++i)
      if (share[i] <= least + 0.02) return candidates[i];
    return first;
  }

  /// Up to about 300 of a group's drawn points, in the world frame.
  static void AddPoints(const Group& group, std::vector<Eigen::Vector3d>* points) {
    vtkIdType total = 0;
    for (const auto& actor : group.actors) {
      vtkPolyData* poly = vtkPolyData::SafeDownCast(actor->GetMapper()->GetInput());
      if (poly) total += poly->GetNumberOfPoints();
    }
    const vtkIdType stride = std::max<vtkIdType>(1, total / 300);
    for (const auto& actor : group.actors) {
      vtkPolyData* poly = vtkPolyData::SafeDownCast(actor->GetMapper()->GetInput());
      if (!poly || poly->GetNumberOfPoints() == 0) continue;
      vtkMatrix4x4* m = actor->GetMatrix();
      for (vtkIdType i = 0; i < poly->GetNumberOfPoints(); i += stride) {
        double p[3];
        poly->GetPoint(i, p);
        const double in[4] = {p[0], p[1], p[2], 1.0};
        double out[4];
        m->MultiplyPoint(in, out);
        points->emplace_back(out[0], out[1], out[2]);
      }
    }
  }

  void BuildRobot() {
    const robot::RobotModel& r = *robot;
    // A link wearing another description's meshes is drawn in them (robot_defaults.hpp,
    // "appearance"), otherwise in its own visual shapes, else its collision shapes.
    dressing = kinematics::DressRobot(r);
    for (int l = 0; l < r.num_links(); ++l) {
      const robot::Link& link = r.link(l);
      const auto& shapes = !dressing.worn[l].empty() ? dressing.worn[l]
                           : link.visuals.empty()    ? link.collisions
                                                     : link.visuals;
      for (const robot::Geometry& g : shapes) {
        vtkSmartPointer<vtkPolyData> poly = ShapePolyData(g);
        if (!poly) continue;
        auto actor = Add("robot", poly);
        if (actor) links.push_back({l, g.X_LG, actor, &g});
      }
    }
    state = std::make_unique<robot::RobotState>(r);
    kinematics::ForwardKinematics(r, r.neutral_configuration(), state.get());
    PoseRobot();
  }

  void PoseRobot() {
    if (!state) return;
    for (const LinkActor& la : links) {
      if (la.link < static_cast<int>(state->X_WL.size())) {
        la.actor->SetUserMatrix(ToVtk(state->X_WL[la.link] * la.X_LG));
      }
    }
  }
};

Scene::Scene(std::shared_ptr<const patient::PatientModel> patient,
             std::shared_ptr<const robot::RobotModel> robot, SceneStyle style)
    : impl_(std::make_unique<Impl>()) {
  impl_->patient = std::move(patient);
  impl_->robot = std::move(robot);
  impl_->style = std::move(style);
  if (impl_->patient) {
    impl_->BuildPatient();
  } else {
    impl_->BuildFloor();
  }
  if (impl_->robot) impl_->BuildRobot();
  // The teaching pointer: its tip a sphere, its body a cone behind the tip along its -z; hidden
  // until placed.
  vtkNew<vtkAppendPolyData> pointer;
  pointer->AddInputData(Sphere(Eigen::Vector3d::Zero(), 0.004));
  vtkNew<vtkConeSource> body;
  body->SetCenter(0, 0, -0.0165);
  body->SetDirection(0, 0, 1);  // apex toward the tip
  body->SetHeight(0.025);
  body->SetRadius(0.004);
  body->SetResolution(20);
  pointer->AddInputData(Output(body));
  impl_->Add("pointer", Output(pointer));
}

void Scene::SetPointer(const Eigen::Isometry3d& X_WP, bool visible) {
  impl_->pointer_shown = visible;
  if (auto* g = impl_->FindGroup("pointer")) {
    for (auto& a : g->actors) a->SetUserMatrix(ToVtk(X_WP));
    impl_->ApplyStyle(*g);
  }
}

Scene::~Scene() = default;

const patient::PatientModel* Scene::patient() const { return impl_->patient.get(); }
const robot::RobotModel* Scene::robot() const { return impl_->robot.get(); }
const std::vector<std::string>& Scene::robot_notes() const { return impl_->dressing.notes; }
const SceneStyle& Scene::style() const { return impl_->style; }

std::vector<std::string> Scene::groups() const {
  std::vector<std::string> out;
  for (const auto& g : impl_->groups) out.push_back(g.name);
  return out;
}

void Scene::SetColour(const std::string& group, const Eigen::Vector3d& rgb) {
  impl_->style.colours[group] = rgb;
  for (const auto& g : impl_->groups) impl_->ApplyStyle(g);
}
void Scene::SetOpacity(const std::string& group, double opacity) {
  impl_->style.opacities[group] = std::clamp(opacity, 0.0, 1.0);
  if (auto* g = impl_->FindGroup(group)) impl_->ApplyStyle(*g);
}
void Scene::SetVisible(const std::string& group, bool visible) {
  impl_->style.visible[group] = visible;
  for (const auto& g : impl_->groups) impl_->ApplyStyle(g);
  impl_->StyleLabels();
}
void Scene::SetBackground(const Eigen::Vector3d& rgb) { impl_->style.background = rgb; }
void Scene::SetFlat(bool flat) {
  impl_->style.flat = flat;
  for (const auto& g : impl_->groups) impl_->ApplyStyle(g);
  impl_->StyleLabels();
}

void Scene::ShowPlan(const planners::PlanFile& file, std::size_t index) {
  TROCAR_THROW_UNLESS(index < file.plans.size(),
                      file.path << ": has " << file.plans.size() << " plans, not " << index + 1);
  const planners::StoredPlan& plan = file.plans[index];
  const std::string where = file.path + ": plan " + std::to_string(index + 1);
  if (impl_->robot) {
    SetRobotState(planners::NominalState(*impl_->robot, plan, where));
  }
  // The floor is the one the plan's cart stands on: lower than z = 0 when the plan raised the
  // table (Placement::table_raise; the world is the table's).
  if (Impl::Group* floor = impl_->FindGroup("floor")) {
    Eigen::Isometry3d X_W = Eigen::Isometry3d::Identity();
    X_W.translation().z() = plan.cart_z;
    for (auto& actor : floor->actors) actor->SetUserMatrix(ToVtk(X_W));
  }
  vtkNew<vtkAppendPolyData> ports, pivots;
  for (const planners::StoredPort& port : plan.ports) {
    ports->AddInputData(Sphere(port.p_W, 0.006));
    pivots->AddInputData(Sphere(port.rcm_W, 0.004));
  }
  impl_->ReplaceGroup("ports", plan.ports.empty() ? nullptr : Output(ports));
  // Each port labelled with its arm and space ("psm1 ICS-L3").
  impl_->RemoveLabels("ports");
  for (const planners::StoredPort& port : plan.ports)
    impl_->AddLabel("ports", port.arm + " " + port.candidate, port.p_W);
  impl_->AddLabelsToRenderers();
  impl_->ReplaceGroup("pivots", plan.ports.empty() ? nullptr : Output(pivots));
  std::vector<Eigen::Vector3d> points, normals;
  for (const planners::StoredSample& s : file.samples) {
    points.push_back(s.p_W);
    normals.push_back(s.n_W);
  }
  impl_->ReplaceGroup("cones", Cones(points, normals, 0.02, 30 * kPi / 180));
}

void Scene::SetRobotState(const robot::RobotState& state) {
  TROCAR_THROW_UNLESS(impl_->robot, "the scene has no robot to pose");
  *impl_->state = state;
  impl_->PoseRobot();
}

const robot::RobotState* Scene::robot_state() const { return impl_->state.get(); }

void Scene::HighlightLinks(const std::vector<int>& colliding, const std::vector<int>& near) {
  impl_->highlighted = colliding;
  impl_->near = near;
  if (auto* g = impl_->FindGroup("robot")) impl_->ApplyStyle(*g);
}

CameraPose FramePoints(const std::vector<Eigen::Vector3d>& p_W, double aspect,
                       const Eigen::Vector3d& direction_W, const Eigen::Vector3d& up_W) {
  TROCAR_THROW_UNLESS(!p_W.empty(), "framing: no points to frame");
  Eigen::Vector3d lo = p_W[0], hi = p_W[0];
  for (const auto& p : p_W) lo = lo.cwiseMin(p), hi = hi.cwiseMax(p);
  const Eigen::Vector3d centre = (lo + hi) / 2;
  double radius = 0.02;
  for (const auto& p : p_W) radius = std::max(radius, (p - centre).norm());
  CameraPose pose;
  const double half = pose.view_angle_deg / 2 * kPi / 180;
  const double fit = std::min(half, std::atan(std::tan(half) * std::max(aspect, 1e-3)));
  Eigen::Vector3d d =
      direction_W.norm() > 1e-9 ? direction_W.normalized() : Eigen::Vector3d::UnitZ();
  Eigen::Vector3d up = up_W - up_W.dot(d) * d;
  if (up.norm() < 1e-6)
    up = (std::abs(d.z()) < 0.9 ? Eigen::Vector3d::UnitZ() : Eigen::Vector3d::UnitX());
  pose.focal_point = centre;
  pose.position = centre + d * (radius / std::sin(fit) * 1.05);
  pose.view_up = up.normalized();
  return pose;
}

CameraPose Scene::ExternalCamera(double aspect, Framing framing) const {
  if ((framing == Framing::kTargets || framing == Framing::kPorts) && impl_->patient) {
    const patient::PatientModel& m = *impl_->patient;
    const Eigen::Isometry3d X_PW = m.X_WP.inverse();
    std::vector<Eigen::Vector3d> ports, points;
    if (const auto* group = impl_->FindGroup("ports")) impl_->AddPoints(*group, &ports);
    if (framing == Framing::kTargets) {
      // The targets and the ports, from the patient's front turned toward the ports' side and
      // the head, the head up: the LAD on the heart's front and the LIMA on the chest wall's
      // back face both face this way.
      for (const patient::Target& t : m.targets)
        for (const Eigen::Vector3d& p : t.points) points.push_back(m.X_WP * p);
      if (!points.empty()) {
        Eigen::Vector3d centre = Eigen::Vector3d::Zero();
        for (const auto& p : points) centre += p;
        centre /= static_cast<double>(points.size());
        double side = 0;  // the ports' side: +1 the patient's left
        for (const auto& p : ports) side += (X_PW * p).x() - (X_PW * centre).x();
        points.insert(points.end(), ports.begin(), ports.end());
        const Eigen::Vector3d d_P =
            Eigen::Vector3d(side < 0 ? -0.55 : 0.55, -1.0, 0.35).normalized();
        return FramePoints(points, aspect, m.X_WP.linear() * d_P,
                           m.X_WP.linear() * Eigen::Vector3d::UnitZ());
      }
    } else if (!ports.empty()) {
      // The ports on the chest, close: from outside the body over their middle (away from the
      // body's long axis, a little from the head), 3 cm of chest around them.
      Eigen::Vector3d centre_P = Eigen::Vector3d::Zero();
      for (const auto& p : ports) centre_P += X_PW * p;
      centre_P /= static_cast<double>(ports.size());
      const Eigen::Vector3d axis_P = 0.5 * (m.body_min_P + m.body_max_P);
      Eigen::Vector3d out_P = centre_P - axis_P;
      out_P.z() = 0;
      if (out_P.norm() < 1e-6) out_P = -Eigen::Vector3d::UnitY();  // the front
      out_P = out_P.normalized() + Eigen::Vector3d(0, 0, 0.25);
      points = ports;
      const Eigen::Vector3d centre_W = m.X_WP * centre_P;
      double radius = 0;
      for (const auto& p : ports) radius = std::max(radius, (p - centre_W).norm());
      // A ring of points 3 cm beyond the farthest port keeps some chest around them.
      const Eigen::Vector3d u = m.X_WP.linear() * Eigen::Vector3d::UnitZ();
      const Eigen::Vector3d v = u.cross(m.X_WP.linear() * out_P.normalized()).normalized();
      for (int k = 0; k < 8; ++k) {
        const double a = k * kPi / 4;
        points.push_back(centre_W + (radius + 0.03) * (std::cos(a) * u + std::sin(a) * v));
      }
      return FramePoints(points, aspect, m.X_WP.linear() * out_P, u);
    }
  }
  const auto* skin_group = impl_->FindGroup("skin");
  const bool chest = framing == Framing::kChest && skin_group && !skin_group->actors.empty();
  // Bounds of the patient, the table and the robot (not the floor); for the chest, the skin's.
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(1e9), hi = Eigen::Vector3d::Constant(-1e9);
  for (const auto& g : impl_->groups) {
    if (g.name == "floor") continue;
    if (chest && g.name != "skin") continue;
    for (const auto& a : g.actors) {
      double b[6];
      a->GetBounds(b);
      if (!(b[0] <= b[1])) continue;
      lo = lo.cwiseMin(Eigen::Vector3d(b[0], b[2], b[4]));
      hi = hi.cwiseMax(Eigen::Vector3d(b[1], b[3], b[5]));
    }
  }
  if (!(lo.array() <= hi.array()).all()) {
    lo = -Eigen::Vector3d::Ones();
    hi = Eigen::Vector3d::Ones();
  }
  CameraPose pose;
  // Between the middle of everything and the patient (the subject), which the view keeps central.
  Eigen::Vector3d centre = (lo + hi) / 2;
  if (const auto* skin = impl_->FindGroup("skin"); skin && !skin->actors.empty()) {
    double b[6];
    skin->actors[0]->GetBounds(b);
    centre = 0.5 * centre + 0.5 * Eigen::Vector3d((b[0] + b[1]) / 2, (b[2] + b[3]) / 2, (b[4] + b[5]) / 2);
  }
  pose.focal_point = centre;
  // The chest: its bounds' sphere a little inside the view (the box's corners are air).
  const double radius = chest ? std::max(0.05, 0.8 * (hi - lo).norm() / 2)
                              : std::max(0.2, (hi - lo).norm() / 2);
  // From the side of the patient away from the cart (so that the arms are seen over the
  // patient, not from behind the cart), toward the foot end, from above.
  Eigen::Vector3d horizontal(-0.55, -0.75, 0);
  if (impl_->robot && impl_->state) {
    Eigen::Vector3d away = centre - impl_->state->X_WB.translation();
    away.z() = 0;
    if (away.norm() > 0.05) horizontal = away.normalized() + Eigen::Vector3d(-0.45, 0, 0);
  }
  const double half = pose.view_angle_deg / 2 * kPi / 180;
  const double half_h = std::atan(std::tan(half) * std::max(aspect, 1e-3));
  const double fit = std::min(half, half_h);
  const double distance = radius / std::sin(fit) * 0.7;
  Eigen::Vector3d direction = (horizontal.normalized() + Eigen::Vector3d(0, 0, 1.0)).normalized();
  if (chest) direction = impl_->LeastHiddenDirection(centre, distance, horizontal);
  pose.position = pose.focal_point + direction * distance;
  pose.view_up = Eigen::Vector3d::UnitZ();
  return pose;
}

CameraPose Scene::OnFrame(const FrameCamera& camera) const {
  TROCAR_THROW_UNLESS(impl_->robot && impl_->state, "a camera on frame '" << camera.frame
                                                    << "' needs a robot in the scene");
  const robot::Frame& frame = impl_->robot->GetFrame(camera.frame);
  const Eigen::Isometry3d X_WF = kinematics::FramePose(*impl_->state, frame);
  const Eigen::Vector3d axis_F = camera.axis_F.normalized();
  const Eigen::Vector3d e = std::abs(axis_F.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
  const Eigen::Vector3d up_F = (e - axis_F * axis_F.dot(e)).normalized();
  CameraPose pose;
  pose.position = X_WF.translation();
  pose.focal_point = pose.position + X_WF.linear() * axis_F * 0.08;
  pose.view_up = X_WF.linear() * up_F;
  pose.view_angle_deg = camera.view_angle_deg;
  return pose;
}

bool SoftwareRendering(vtkRenderWindow* window) {
  const char* caps = window ? window->ReportCapabilities() : nullptr;
  return caps && IsSoftwareRenderer(caps);
}

bool IsSoftwareRenderer(const std::string& text) {
  const auto line = text.find("OpenGL renderer string:");
  if (line == std::string::npos) return false;
  const std::string renderer = text.substr(line, text.find('\n', line) - line);
  for (const char* software : {"llvmpipe", "softpipe", "swrast", "Software Rasterizer"})
    if (renderer.find(software) != std::string::npos) return true;
  return false;
}

Image ReadPixels(vtkRenderWindow* window, int width, int height) {
  vtkNew<vtkWindowToImageFilter> grab;
  grab->SetInput(window);
  grab->SetInputBufferTypeToRGB();
  grab->ReadFrontBufferOff();
  grab->Update();
  vtkImageData* data = grab->GetOutput();
  int dims[3];
  data->GetDimensions(dims);
  TROCAR_THROW_UNLESS(dims[0] == width && dims[1] == height && data->GetNumberOfScalarComponents() == 3,
                      "the renderer returned a " << dims[0] << "x" << dims[1] << " image, not "
                                                 << width << "x" << height);
  Image image;
  image.width = width;
  image.height = height;
  image.rgb.resize(static_cast<std::size_t>(3) * width * height);
  const auto* pixels = static_cast<const unsigned char*>(data->GetScalarPointer());
  for (int y = 0; y < height; ++y) {  // VTK's rows run bottom to top
    std::copy_n(pixels + static_cast<std::size_t>(3) * width * (height - 1 - y), 3 * width,
                image.rgb.begin() + static_cast<std::ptrdiff_t>(3) * width * y);
  }
  return image;
}

bool AdaptToRenderer(vtkRenderWindow* window) {
  if (!window || window->GetMultiSamples() == 0 || !SoftwareRendering(window)) return false;
  window->SetMultiSamples(0);
  return true;
}

namespace {

// AdaptToRenderer once, at the end of the window's first frame drawn.
class AdaptOnce : public vtkCommand {
 public:
  static AdaptOnce* New() { return new AdaptOnce; }
  void Execute(vtkObject* caller, unsigned long, void*) override {
    if (done_) return;
    done_ = true;
    AdaptToRenderer(vtkRenderWindow::SafeDownCast(caller));
  }

 private:
  bool done_ = false;
};

}  // namespace

void AdaptAfterFirstFrame(vtkRenderWindow* window) {
  vtkNew<AdaptOnce> adapt;
  window->AddObserver(vtkCommand::EndEvent, adapt);
}

void Scene::AddTo(vtkRenderer* renderer) const {
  for (const auto& g : impl_->groups)
    for (const auto& a : g.actors) renderer->AddActor(a);
  auto& renderers = impl_->renderers;
  renderers.erase(
      std::remove_if(renderers.begin(), renderers.end(), [](const auto& r) { return !r; }),
      renderers.end());
  renderers.push_back(renderer);
  impl_->AddLabelsToRenderers();
  renderer->SetBackground(impl_->style.background.data());
}

void Scene::Apply(const CameraPose& pose, vtkRenderer* renderer, const FrameCamera* scope) {
  vtkCamera* camera = renderer->GetActiveCamera();
  camera->SetPosition(pose.position.data());
  camera->SetFocalPoint(pose.focal_point.data());
  camera->SetViewUp(pose.view_up.data());
  camera->SetViewAngle(pose.view_angle_deg);
  camera->OrthogonalizeViewUp();
  if (scope) {
    renderer->AutomaticLightCreationOff();
    renderer->RemoveAllLights();
    vtkNew<vtkLight> light;
    light->SetLightTypeToHeadlight();
    light->SetIntensity(scope->light_intensity);
    renderer->AddLight(light);
    // A scope sees from about a centimetre (its own tip's shapes are nearer).
    camera->SetClippingRange(0.012, 3.0);
  } else {
    renderer->ResetCameraClippingRange();
  }
}

void Scene::LeaveOutCarrier(vtkRenderer* renderer, const FrameCamera& scope,
                            const CameraPose& pose) const {
  const robot::RobotModel* r = impl_->robot.get();
  std::vector<char> carrier(r ? r->num_links() : 0, 0);
  if (r) {
    int link = -1;
    for (const robot::Frame& f : r->frames())
      if (f.name == scope.frame) link = f.link;
    if (link < 0) link = r->FindLink(scope.frame);
    // The carrier and the links welded to it: up through fixed parent joints, then down through
    // fixed child joints.
    while (link >= 0 && r->link(link).parent_joint >= 0 &&
           !r->joint(r->link(link).parent_joint).movable())
      link = r->joint(r->link(link).parent_joint).parent_link;
    std::vector<int> open;
    if (link >= 0) open.push_back(link);
    while (!open.empty()) {
      const int l = open.back();
      open.pop_back();
      carrier[l] = 1;
      for (int j : r->link(l).child_joints)
        if (!r->joint(j).movable()) open.push_back(r->joint(j).child_link);
    }
  }
  auto holds_camera = [&](vtkActor* actor) {
    double b[6];
    actor->GetBounds(b);
    const double margin = 0.001;
    for (int k = 0; k < 3; ++k)
      if (pose.position[k] < b[2 * k] - margin || pose.position[k] > b[2 * k + 1] + margin)
        return false;
    return true;
  };
  for (const auto& la : impl_->links) {
    if ((la.link >= 0 && la.link < static_cast<int>(carrier.size()) && carrier[la.link]) ||
        holds_camera(la.actor))
      renderer->RemoveActor(la.actor);
    else
      renderer->AddActor(la.actor);
  }
}

bool Scene::ShowsOverlay(const std::string& name) const {
  const SceneStyle& style = impl_->style;
  if (!style.flat) return style.Visible(name);
  const auto it = style.visible.find(name);
  return it != style.visible.end() && it->second;
}

void Scene::AddOrientationMarker(vtkRenderer* renderer, const CameraPose& view) const {
  // The patient's directions in W: LPS's +x is left, -y anterior, +z head; without a patient,
  // the table's (head toward +x_W).
  Eigen::Matrix3d R_WP = Eigen::Matrix3d::Identity();
  if (impl_->patient) R_WP = impl_->patient->X_WP.linear();
  const struct {
    const char* group;
    const char* letter;
    Eigen::Vector3d d_W;
  } axes[] = {{"marker:head", "H", R_WP * Eigen::Vector3d::UnitZ()},
              {"marker:left", "L", R_WP * Eigen::Vector3d::UnitX()},
              {"marker:anterior", "A", R_WP * -Eigen::Vector3d::UnitY()}};
  vtkCamera* camera = renderer->GetActiveCamera();
  const Eigen::Vector3d forward = (view.focal_point - view.position).normalized();
  const Eigen::Vector3d eye = -5.8 * forward;  // the arrows and their letters fit the square
  camera->SetPosition(eye.data());
  camera->SetFocalPoint(0, 0, 0);
  camera->SetViewUp(view.view_up.data());
  camera->SetViewAngle(30);
  camera->OrthogonalizeViewUp();
  for (const auto& axis : axes) {
    Eigen::Vector3d colour = impl_->style.Colour(axis.group);
    vtkNew<vtkArrowSource> arrow;
    arrow->SetShaftRadius(0.05);
    arrow->SetTipRadius(0.13);
    arrow->SetTipLength(0.3);
    arrow->SetShaftResolution(16);
    arrow->SetTipResolution(16);
    vtkNew<vtkPolyDataMapper> mapper;
    mapper->SetInputConnection(arrow->GetOutputPort());
    vtkNew<vtkActor> actor;
    actor->SetMapper(mapper);
    // The arrow source points along +x: turn it onto the axis.
    Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
    X.linear() = Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d::UnitX(), axis.d_W).toRotationMatrix();
    actor->SetUserMatrix(ToVtk(X));
    vtkNew<vtkVectorText> text;
    text->SetText(axis.letter);
    vtkNew<vtkPolyDataMapper> text_mapper;
    text_mapper->SetInputConnection(text->GetOutputPort());
    vtkNew<vtkFollower> label;
    label->SetMapper(text_mapper);
    label->SetScale(0.32);
    Eigen::Vector3d at = 1.25 * axis.d_W;
    label->SetPosition(at.data());
    label->SetCamera(camera);
    for (vtkActor* a : {static_cast<vtkActor*>(actor), static_cast<vtkActor*>(label)}) {
      a->GetProperty()->SetColor(colour.data());
      if (impl_->style.flat) {
        a->GetProperty()->SetAmbient(1.0);
        a->GetProperty()->SetDiffuse(0.0);
        a->GetProperty()->SetSpecular(0.0);
      }
      renderer->AddActor(a);
    }
  }
  renderer->ResetCameraClippingRange();
}

void Scene::ShowReachability(const planners::PlanFile& file, std::size_t index) {
  const planners::Reachability reach = planners::TargetReachability(file, index);
  std::map<planners::ReachClass, vtkSmartPointer<vtkAppendPolyData>> tubes;
  std::map<planners::ReachClass, int> parts;
  for (auto c :
       {planners::ReachClass::kServed, planners::ReachClass::kPartly, planners::ReachClass::kNone})
    tubes[c] = vtkSmartPointer<vtkAppendPolyData>::New();
  if (impl_->patient) {
    const patient::PatientModel& m = *impl_->patient;
    for (const patient::Target& t : m.targets) {
      // The target's samples along it; each colours the stretch of the curve nearer to it than
      // to its neighbours (the first from the curve's start, the last to its end).
      std::vector<int> along;
      for (std::size_t s = 0; s < file.samples.size(); ++s)
        if (file.samples[s].target == t.name) along.push_back(static_cast<int>(s));
      if (along.empty() || t.points.size() < 2) continue;
      std::sort(along.begin(), along.end(), [&](int a, int b) {
        return file.samples[a].arc_length < file.samples[b].arc_length;
      });
      const std::vector<Eigen::Vector3d> p_W = ToWorld(t.points, m.X_WP);
      std::vector<double> arc(p_W.size(), 0.0);
      for (std::size_t i = 1; i < p_W.size(); ++i)
        arc[i] = arc[i - 1] + (p_W[i] - p_W[i - 1]).norm();
      for (std::size_t k = 0; k < along.size(); ++k) {
        const double here = file.samples[along[k]].arc_length;
        const double a = k == 0 ? 0.0 : 0.5 * (file.samples[along[k - 1]].arc_length + here);
        const double b = k + 1 == along.size()
                             ? arc.back()
                             : 0.5 * (here + file.samples[along[k + 1]].arc_length);
        if (auto tube = Tube(SubCurve(p_W, arc, a, b), 0.0028)) {
          tubes[reach.per_sample[along[k]]]->AddInputData(tube);
          ++parts[reach.per_sample[along[k]]];
        }
      }
    }
  }
  const std::pair<planners::ReachClass, const char*> groups[] = {
      {planners::ReachClass::kServed, "reach:served"},
      {planners::ReachClass::kPartly, "reach:partly"},
      {planners::ReachClass::kNone, "reach:none"}};
  for (const auto& [c, name] : groups)
    impl_->ReplaceGroup(name, parts[c] ? Output(tubes[c]) : nullptr);
  // Each target named with its served share ("LAD: 4 of 8 served"), at its middle.
  impl_->GetGroup("reach:labels");
  impl_->RemoveLabels("reach:labels");
  if (impl_->patient) {
    const patient::PatientModel& m = *impl_->patient;
    for (const patient::Target& t : m.targets) {
      int of = 0, served = 0;
      for (std::size_t s = 0; s < file.samples.size(); ++s) {
        if (file.samples[s].target != t.name) continue;
        ++of;
        served += reach.per_sample[s] == planners::ReachClass::kServed;
      }
      if (of == 0 || t.points.empty()) continue;
      impl_->AddLabel(
          "reach:labels",
          t.name + ": " + std::to_string(served) + " of " + std::to_string(of) + " served",
          m.X_WP * t.points[t.points.size() / 2]);
    }
  }
  impl_->AddLabelsToRenderers();
}

void Scene::AddLegend(vtkRenderer* renderer) const {
  std::vector<std::pair<std::string, std::string>> entries;  // group, label
  for (const auto& g : impl_->groups) {
    if (g.actors.empty() || !impl_->style.Visible(g.name)) continue;
    if (g.name == "floor" || g.name == "cones" || g.name == "pointer") continue;
    const bool target = g.name.rfind("target:", 0) == 0;
    std::string label = target ? g.name.substr(7) + " (target)" : g.name;
    if (g.name == "candidates") label = "port candidates";
    if (g.name == "reach:served") label = "served: all instruments, seen";
    if (g.name == "reach:partly") label = "reached by some arms";
    if (g.name == "reach:none") label = "reached by no instrument";
    entries.push_back({g.name, label});
  }
  if (entries.empty()) return;
  vtkNew<vtkPlaneSource> square;
  square->Update();
  vtkNew<vtkLegendBoxActor> legend;
  legend->SetNumberOfEntries(static_cast<int>(entries.size()));
  for (std::size_t i = 0; i < entries.size(); ++i) {
    Eigen::Vector3d c = impl_->style.Colour(entries[i].first);
    legend->SetEntry(static_cast<int>(i), square->GetOutput(), entries[i].second.c_str(), c.data());
  }
  legend->BorderOff();
  legend->UseBackgroundOn();  // the entries' names readable over any scene
  legend->SetBackgroundColor(0.08, 0.08, 0.10);
  legend->SetBackgroundOpacity(0.7);
  legend->GetEntryTextProperty()->SetFontSize(14);
  legend->GetEntryTextProperty()->SetColor(impl_->style.flat ? 1.0 : 0.95, 1.0, 1.0);
  legend->GetPositionCoordinate()->SetCoordinateSystemToNormalizedViewport();
  legend->GetPositionCoordinate()->SetValue(0.78, 0.02);
  legend->GetPosition2Coordinate()->SetCoordinateSystemToNormalizedViewport();
  legend->GetPosition2Coordinate()->SetValue(0.21, std::min(0.05 * entries.size(), 0.5));
  renderer->AddViewProp(legend);
}

long Scene::triangle_count() const {
  long n = 0;
  for (const auto& g : impl_->groups) {
    if (!impl_->style.Visible(g.name)) continue;
    for (const auto& a : g.actors) {
      if (auto* poly = vtkPolyData::SafeDownCast(a->GetMapper()->GetInput())) {
        n += poly->GetNumberOfPolys() + poly->GetNumberOfStrips();
      }
    }
  }
  return n;
}

int Scene::actor_count() const {
  int n = 0;
  for (const auto& g : impl_->groups) n += static_cast<int>(g.actors.size());
  return n;
}

Eigen::Vector3d EulerXyzDeg(const Eigen::Matrix3d& R) {
  // R = Rx(a) Ry(b) Rz(c): R(0,2) = sin b.
  const double b = std::asin(std::clamp(R(0, 2), -1.0, 1.0));
  double a = 0, c = 0;
  if (std::abs(R(0, 2)) < 1 - 1e-12) {
    a = std::atan2(-R(1, 2), R(2, 2));
    c = std::atan2(-R(0, 1), R(0, 0));
  } else {  // gimbal lock: a and c turn about the same axis; put it all in a
    a = std::atan2(R(2, 1), R(1, 1));
  }
  return Eigen::Vector3d(a, b, c) * 180 / kPi;
}

ViewSpec ViewSpec::Parse(const std::string& text) {
  ViewSpec v;
  if (text == "external") return v;
  if (text == "room") {
    v.kind = Kind::kRoom;
    return v;
  }
  if (text == "targets") {
    v.kind = Kind::kTargets;
    return v;
  }
  if (text == "ports") {
    v.kind = Kind::kPorts;
    return v;
  }
  if (text == "endoscope") {
    v.kind = Kind::kEndoscope;
    return v;
  }
  if (text.rfind("frame:", 0) == 0 && text.size() > 6) {
    v.kind = Kind::kFrame;
    v.camera.frame = text.substr(6);
    return v;
  }
  TROCAR_THROW(
      "view '" << text
               << "': expected external, room, targets, ports, endoscope or frame:<robot frame>");
}

CameraPose ViewCamera(const Scene& scene, const ViewSpec& view, double aspect,
                      const planners::StoredPlan* plan, FrameCamera* used) {
  FrameCamera camera = view.camera;
  switch (view.kind) {
    case ViewSpec::Kind::kExternal:
      return scene.ExternalCamera(aspect);
    case ViewSpec::Kind::kRoom:
      return scene.ExternalCamera(aspect, Scene::Framing::kRoom);
    case ViewSpec::Kind::kTargets:
      return scene.ExternalCamera(aspect, Scene::Framing::kTargets);
    case ViewSpec::Kind::kPorts:
      return scene.ExternalCamera(aspect, Scene::Framing::kPorts);
    case ViewSpec::Kind::kEndoscope: {
      TROCAR_THROW_UNLESS(plan && !plan->views.empty(),
                          "the endoscope view needs a plan whose robot has an endoscope arm");
      camera.frame = plan->views.front().frame;
      camera.axis_F = plan->views.front().axis_F;
      break;
    }
    case ViewSpec::Kind::kFrame:
      break;
  }
  if (used) *used = camera;
  return scene.OnFrame(camera);
}

Image Render(const Scene& scene, const Views& views, int width, int height) {
  TROCAR_THROW_UNLESS(width >= 16 && height >= 16 && width <= 8192 && height <= 8192,
                      "image size " << width << "x" << height << ": expected 16..8192 pixels a side");
  TROCAR_THROW_UNLESS(!views.empty(), "a picture needs at least one view");
  const char* display = std::getenv("DISPLAY");
  TROCAR_THROW_UNLESS(display && *display,
                      "rendering needs an X display (DISPLAY is not set): run under "
                      "xvfb-run -a -s \"-screen 0 1280x1024x24\"");
  vtkNew<vtkRenderWindow> window;
  window->SetOffScreenRendering(1);
  window->SetSize(width, height);
  window->SetMultiSamples(0);
  const double n = static_cast<double>(views.size());
  for (std::size_t i = 0; i < views.size(); ++i) {
    vtkNew<vtkRenderer> renderer;
    renderer->SetViewport(i / n, 0, (i + 1) / n, 1);
    scene.AddTo(renderer);
    const bool scope = views[i].first.kind != ViewSpec::Kind::kExternal &&
                       views[i].first.kind != ViewSpec::Kind::kRoom &&
                       views[i].first.kind != ViewSpec::Kind::kTargets &&
                       views[i].first.kind != ViewSpec::Kind::kPorts;
    Scene::Apply(views[i].second, renderer, scope ? &views[i].first.camera : nullptr);
    if (scope) scene.LeaveOutCarrier(renderer, views[i].first.camera, views[i].second);
    window->AddRenderer(renderer);
    if (scope) continue;
    if (scene.ShowsOverlay("legend")) scene.AddLegend(renderer);
    if (scene.ShowsOverlay("orientation")) {
      // A square in the view's lower-left corner, a fifth of its smaller side, over the view.
      const double side = 0.2 * std::min(static_cast<double>(height), width / n);
      vtkNew<vtkRenderer> corner;
      corner->SetViewport(i / n, 0, i / n + side / width, side / height);
      corner->SetLayer(1);
      corner->InteractiveOff();
      window->SetNumberOfLayers(2);
      scene.AddOrientationMarker(corner, views[i].second);
      window->AddRenderer(corner);
    }
  }
  window->Render();
  Image image = ReadPixels(window, width, height);
  // The renderers give the scene's actors' graphics resources back, so that they can be drawn
  // in another window.
  window->Finalize();
  return image;
}

void Screenshot(const Scene& scene, const Views& views, int width, int height,
                const std::string& path) {
  WritePng(Render(scene, views, width, height), path);
}

}  // namespace trocar::viz
