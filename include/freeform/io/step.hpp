#pragma once
// The designed surface as a STEP part (ISO 10303-21, schema AP214) through Open CASCADE
// (OCCT 7.6): one closed solid whose top face is the fitted bicubic B-spline of
// surface/bspline.hpp, exactly, not a tessellation of it. Only where freeform is built with
// OCCT (target freeform::step, which defines FREEFORM_WITH_OCCT; docs/export.md).
//
// The part, in its own frame (the surface frame: x = u, y = v, z = w) and in millimetres,
// the unit a machinist's CAM program expects (the STEP file says so; metres × 1000):
//   top     the spline itself: poles (pole_u, pole_v, z), degree 3 both ways, the clamped
//           knot vectors of the fit. Since the poles stand at the Greville abscissae,
//           x(s, t) = s and y(s, t) = t: the B-spline's parameters are x and y in mm;
//   sides   four planar walls x = const and y = const, each bounded above by the top
//           face's boundary curve (a spline curve from the boundary row of poles, which lies
//           in that plane because those poles all do) and by straight edges down to
//   back    a flat face at w = back_w.
// The outline is always the rectangle: for an elliptical aperture the fit covers the whole
// rectangle too (surface/bspline.hpp), and the part carries it; the optics outside the
// ellipse are then the fit's continuation, which a machinist may cut away.
//
// The faces share their edges and vertices (one edge object per boundary, used forward by
// one face and reversed by the other), so the shell is closed by construction: no sewing,
// which on a 515 × 515-pole face would cost seconds and could merge or split edges by
// tolerance. The walls get their orientation from OCCT's face builder (wire oriented to
// bound the finite region of an outward-facing plane); BRepLib::OrientClosedSolid then
// guarantees a positive volume whatever the sign of the top face's normal.
//
// Reading back (read_step, StepPart) is what judges an exported part: OCCT's re-read
// geometry, not our spline, is checked (validity, closedness, volume) and sampled
// (StepPart::point_m, normal), so a unit, knot or pole mistake in the writer shows up as
// a difference to BSplineSurface::eval.
//
// OCCT keeps the STEP settings (schema, units, product name) in process-wide statics
// (Interface_Static): write_step and read_step set the ones they rely on every time,
// under one mutex, so two calls of ours never interleave; other code in the process that
// uses OCCT's STEP translators at the same time is not covered by that lock.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <mutex>
#include <sstream>
#include <string>
#include <vector>

#include <BRepBuilderAPI_MakeEdge.hxx>
#include <BRepBuilderAPI_MakeFace.hxx>
#include <BRepBuilderAPI_MakeVertex.hxx>
#include <BRepBuilderAPI_MakeWire.hxx>
#include <BRepCheck_Analyzer.hxx>
#include <BRepGProp.hxx>
#include <BRepLib.hxx>
#include <BRep_Builder.hxx>
#include <BRep_Tool.hxx>
#include <GProp_GProps.hxx>
#include <Geom2d_Line.hxx>
#include <Geom_BSplineCurve.hxx>
#include <Geom_BSplineSurface.hxx>
#include <Geom_RectangularTrimmedSurface.hxx>
#include <IFSelect_ReturnStatus.hxx>
#include <Interface_Static.hxx>
#include <Message.hxx>
#include <Message_Gravity.hxx>
#include <Message_Messenger.hxx>
#include <Message_Printer.hxx>
#include <Precision.hxx>
#include <STEPControl_Reader.hxx>
#include <STEPControl_Writer.hxx>
#include <StepBasic_Product.hxx>
#include <StepAP214.hxx>
#include <StepAP214_Protocol.hxx>
#include <StepData_Protocol.hxx>
#include <StepData_StepModel.hxx>
#include <StepData_StepWriter.hxx>
#include <Standard_Failure.hxx>
#include <TCollection_AsciiString.hxx>
#include <TCollection_HAsciiString.hxx>
#include <TColStd_Array1OfInteger.hxx>
#include <TColStd_Array1OfReal.hxx>
#include <TColgp_Array1OfPnt.hxx>
#include <TColgp_Array2OfPnt.hxx>
#include <TopExp.hxx>
#include <TopExp_Explorer.hxx>
#include <TopTools_IndexedDataMapOfShapeListOfShape.hxx>
#include <TopTools_ListOfShape.hxx>
#include <TopoDS.hxx>
#include <TopoDS_Edge.hxx>
#include <TopoDS_Face.hxx>
#include <TopoDS_Shape.hxx>
#include <TopoDS_Shell.hxx>
#include <TopoDS_Solid.hxx>
#include <TopoDS_Vertex.hxx>
#include <TopoDS_Wire.hxx>
#include <gp_Pln.hxx>
#include <gp_Pnt.hxx>
#include <gp_Vec.hxx>

#include "../core/error.hpp"
#include "../core/math.hpp"
#include "../surface/bspline.hpp"
#include "file.hpp"

namespace freeform::io {

// How the spline becomes a solid: the height of the flat back face, and the name the
// STEP file gives the part (its PRODUCT, shown in a CAD program's tree).
struct StepSolid {
    double back_w = 0;  // surface-frame w of the back face, metres; below the spline's lowest point
    std::string name = "freeform surface";  // written as is: keep it ASCII for other readers
};

namespace step_detail {

inline constexpr double mm_per_m = 1000.0;

// One lock for OCCT's process-wide STEP settings (see the top of this file).
inline std::mutex& statics_mutex() {
    static std::mutex m;
    return m;
}

// OCCT reports through its default messenger, which prints to stdout (in colour): transfer
// statistics on every write, parse errors on a bad file. A library must not write to the
// program's stdout (the command line may be printing JSON there), and our callers get
// exceptions instead. While a Quiet is alive the messenger's printers are set aside and
// warnings and failures are collected for the exception's message; the printers are put
// back afterwards. Used under statics_mutex(), like the STEP settings.
class Quiet {
public:
    Quiet() : messenger_(Message::DefaultMessenger()) {
        if (messenger_.IsNull()) return;
        saved_ = messenger_->Printers();
        messenger_->ChangePrinters().Clear();
        messenger_->AddPrinter(collector_);
    }
    ~Quiet() {
        if (!messenger_.IsNull()) messenger_->ChangePrinters() = saved_;
    }
    Quiet(const Quiet&) = delete;
    Quiet& operator=(const Quiet&) = delete;

    // " (OCCT: <first failure or warning>)", or "" when OCCT said nothing of the kind.
    std::string detail() const {
        return collector_->text.empty() ? std::string() : " (OCCT: " + collector_->text + ")";
    }

private:
    class Collector : public Message_Printer {
    public:
        Collector() { SetTraceLevel(Message_Warning); }
        mutable std::string text;

    protected:
        void send(const TCollection_AsciiString& message, const Message_Gravity gravity) const override {
            if (gravity < Message_Warning || !text.empty()) return;
            std::string m(message.ToCString());
            const auto first = m.find_first_not_of(" \t\r\n*"), last = m.find_last_not_of(" \t\r\n*");
            if (first != std::string::npos) text = m.substr(first, std::min<std::size_t>(last - first + 1, 300));
        }
    };
    Handle(Message_Messenger) messenger_;
    Message_SequenceOfPrinters saved_;
    Handle(Collector) collector_ = new Collector();
};

// A length for a message: "0.00123 m" (std::to_string's fixed six decimals would say 0.000000).
inline std::string metres(double x) {
    char buf[40];
    std::snprintf(buf, sizeof buf, "%.9g m", x);
    return buf;
}

// A full clamped knot vector as OCCT wants it: distinct values and their multiplicities
// (4, 1, …, 1, 4 for the fit's knots), scaled to millimetres.
struct Knots {
    std::vector<double> values;
    std::vector<int> mults;
};
inline Knots distinct_knots(const std::vector<double>& full) {
    Knots k;
    for (const double t : full) {
        const double mm = t * mm_per_m;
        if (!k.values.empty() && mm == k.values.back())
            ++k.mults.back();
        else
            k.values.push_back(mm), k.mults.push_back(1);
    }
    return k;
}
inline TColStd_Array1OfReal occt_reals(const std::vector<double>& v) {
    TColStd_Array1OfReal a(1, int(v.size()));
    for (std::size_t i = 0; i < v.size(); ++i) a.SetValue(int(i) + 1, v[i]);
    return a;
}
inline TColStd_Array1OfInteger occt_ints(const std::vector<int>& v) {
    TColStd_Array1OfInteger a(1, int(v.size()));
    for (std::size_t i = 0; i < v.size(); ++i) a.SetValue(int(i) + 1, v[i]);
    return a;
}

// The spline's shape is checked here rather than left to OCCT, whose constructors throw
// Standard_ConstructionError without saying which of our fields is wrong.
inline void check_spline(const BSplineSurface& s) {
    const int deg = BSplineSurface::degree;
    const auto bad = [](const std::string& what) { throw InputError("STEP export: invalid B-spline surface: " + what); };
    if (s.nu < deg + 1 || s.nv < deg + 1) bad("fewer than 4 x 4 poles");
    if (s.knots_u.size() != std::size_t(s.nu + deg + 1) || s.knots_v.size() != std::size_t(s.nv + deg + 1))
        bad("knot vectors do not match the pole counts");
    if (s.pole_u.size() != std::size_t(s.nu) || s.pole_v.size() != std::size_t(s.nv) ||
        s.z.size() != std::size_t(s.nu) * std::size_t(s.nv))
        bad("pole arrays do not match the pole counts");
    for (const auto* k : {&s.knots_u, &s.knots_v})
        for (std::size_t i = 0; i < k->size(); ++i)
            if (!std::isfinite((*k)[i]) || (i > 0 && (*k)[i] < (*k)[i - 1])) bad("knots not finite and non-decreasing");
    if (!(s.u_max() > s.u_min()) || !(s.v_max() > s.v_min())) bad("empty parameter rectangle");
    for (const double z : s.z)
        if (!std::isfinite(z)) bad("non-finite pole height");
}

// The top face's surface: x = pole_u, y = pole_v, z = pole height, all in mm.
inline TColgp_Array2OfPnt occt_poles(const BSplineSurface& s) {
    TColgp_Array2OfPnt poles(1, s.nu, 1, s.nv);
    for (int j = 0; j < s.nv; ++j)
        for (int i = 0; i < s.nu; ++i)
            poles.SetValue(i + 1, j + 1,
                           gp_Pnt(s.pole_u[std::size_t(i)] * mm_per_m, s.pole_v[std::size_t(j)] * mm_per_m,
                                  s.pole(i, j) * mm_per_m));
    return poles;
}

// The twelve edges of the part: the top face's four boundary curves, four vertical
// edges at the corners, the back face's four lines. Corner vertices are shared.
struct PartEdges {
    TopoDS_Edge top_y0, top_y1, top_x0, top_x1;  // top boundary, at v = min / max, u = min / max
    TopoDS_Edge up00, up10, up01, up11;          // back corner → top corner
    TopoDS_Edge back_y0, back_y1, back_x0, back_x1;
    double s0 = 0, s1 = 0, t0 = 0, t1 = 0;       // the top surface's parameter rectangle (mm)
    double x0 = 0, x1 = 0, y0 = 0, y1 = 0, zb = 0;  // the walls' planes and the back's (mm)
};

// The boundary curves are made from the boundary rows of poles with the same knots: a
// clamped spline's edge is exactly the spline curve of its edge poles, and each lies in a
// wall's plane, which goes through those poles (x = pole_u[0] etc.; the knot bound up to
// rounding). Each curve's parameter is the surface parameter along it.
inline PartEdges part_edges(const TColgp_Array2OfPnt& poles, const Knots& ku, const Knots& kv, double back_mm) {
    const int nu = poles.UpperRow(), nv = poles.UpperCol();
    const auto row_curve = [&](bool along_u, int index) {
        const int n = along_u ? nu : nv;
        TColgp_Array1OfPnt p(1, n);
        for (int k = 1; k <= n; ++k) p.SetValue(k, along_u ? poles.Value(k, index) : poles.Value(index, k));
        const Knots& kk = along_u ? ku : kv;
        return Handle(Geom_BSplineCurve)(
            new Geom_BSplineCurve(p, occt_reals(kk.values), occt_ints(kk.mults), BSplineSurface::degree));
    };
    PartEdges e;
    e.s0 = ku.values.front(), e.s1 = ku.values.back(), e.t0 = kv.values.front(), e.t1 = kv.values.back();
    e.x0 = poles.Value(1, 1).X(), e.x1 = poles.Value(nu, 1).X(), e.y0 = poles.Value(1, 1).Y();
    e.y1 = poles.Value(1, nv).Y(), e.zb = back_mm;
    // Corner vertices: top (the corner poles, where a clamped spline passes) and back.
    const auto vertex = [](const gp_Pnt& p) { return BRepBuilderAPI_MakeVertex(p).Vertex(); };
    const TopoDS_Vertex p00 = vertex(poles.Value(1, 1)), p10 = vertex(poles.Value(nu, 1)),
                        p01 = vertex(poles.Value(1, nv)), p11 = vertex(poles.Value(nu, nv));
    const TopoDS_Vertex b00 = vertex(gp_Pnt(e.x0, e.y0, e.zb)), b10 = vertex(gp_Pnt(e.x1, e.y0, e.zb)),
                        b01 = vertex(gp_Pnt(e.x0, e.y1, e.zb)), b11 = vertex(gp_Pnt(e.x1, e.y1, e.zb));
    const auto curve_edge = [](const Handle(Geom_BSplineCurve)& c, const TopoDS_Vertex& a, const TopoDS_Vertex& b,
                               double from, double to) {
        BRepBuilderAPI_MakeEdge m(c, a, b, from, to);
        if (!m.IsDone()) throw Standard_Failure("boundary edge");
        return m.Edge();
    };
    const auto line_edge = [](const TopoDS_Vertex& a, const TopoDS_Vertex& b) {
        BRepBuilderAPI_MakeEdge m(a, b);
        if (!m.IsDone()) throw Standard_Failure("straight edge");
        return m.Edge();
    };
    e.top_y0 = curve_edge(row_curve(true, 1), p00, p10, e.s0, e.s1);
    e.top_y1 = curve_edge(row_curve(true, nv), p01, p11, e.s0, e.s1);
    e.top_x0 = curve_edge(row_curve(false, 1), p00, p01, e.t0, e.t1);
    e.top_x1 = curve_edge(row_curve(false, nu), p10, p11, e.t0, e.t1);
    e.up00 = line_edge(b00, p00), e.up10 = line_edge(b10, p10), e.up01 = line_edge(b01, p01);
    e.up11 = line_edge(b11, p11);
    e.back_y0 = line_edge(b00, b10), e.back_y1 = line_edge(b01, b11), e.back_x0 = line_edge(b00, b01);
    e.back_x1 = line_edge(b10, b11);
    return e;
}

// Top face: the whole parameter rectangle, outer wire counter-clockwise in (s, t) (seen
// from +z, where the surface normal S_s × S_t points since x = s, y = t), with the
// parameter-space lines as the edges' curves on the surface.
inline TopoDS_Face top_face(const Handle(Geom_BSplineSurface)& surface, const PartEdges& e) {
    BRep_Builder builder;
    TopoDS_Face top;
    builder.MakeFace(top, surface, Precision::Confusion());
    const Handle(Geom2d_Line) on_t0 = new Geom2d_Line(gp_Pnt2d(0, e.t0), gp_Dir2d(1, 0));
    const Handle(Geom2d_Line) on_t1 = new Geom2d_Line(gp_Pnt2d(0, e.t1), gp_Dir2d(1, 0));
    const Handle(Geom2d_Line) on_s0 = new Geom2d_Line(gp_Pnt2d(e.s0, 0), gp_Dir2d(0, 1));
    const Handle(Geom2d_Line) on_s1 = new Geom2d_Line(gp_Pnt2d(e.s1, 0), gp_Dir2d(0, 1));
    builder.UpdateEdge(e.top_y0, on_t0, top, Precision::Confusion());
    builder.UpdateEdge(e.top_y1, on_t1, top, Precision::Confusion());
    builder.UpdateEdge(e.top_x0, on_s0, top, Precision::Confusion());
    builder.UpdateEdge(e.top_x1, on_s1, top, Precision::Confusion());
    TopoDS_Wire wire;
    builder.MakeWire(wire);
    builder.Add(wire, e.top_y0);
    builder.Add(wire, e.top_x1);
    builder.Add(wire, e.top_y1.Reversed());
    builder.Add(wire, e.top_x0.Reversed());
    wire.Closed(true);
    builder.Add(top, wire);
    return top;
}

// A planar face with the outward normal `out`, bounded by four edges (any order and
// direction: the wire builder chains them, and MakeFace orients the wire to bound the
// finite region, so the face's normal stays the plane's).
inline TopoDS_Face plane_face(const gp_Pnt& at, const gp_Dir& out, const TopoDS_Edge& a, const TopoDS_Edge& b,
                              const TopoDS_Edge& c, const TopoDS_Edge& d) {
    BRepBuilderAPI_MakeWire w;
    for (const TopoDS_Edge* e : {&a, &b, &c, &d}) w.Add(*e);
    if (!w.IsDone()) throw Standard_Failure("wall wire");
    BRepBuilderAPI_MakeFace f(gp_Pln(at, out), w.Wire(), Standard_True);
    if (!f.IsDone()) throw Standard_Failure("wall face");
    TopoDS_Face face = f.Face();
    TopTools_ListOfShape edges;
    for (TopExp_Explorer x(face, TopAbs_EDGE); x.More(); x.Next()) edges.Append(x.Current());
    BRepLib::BuildPCurveForEdgesOnPlane(edges, face);  // stored, not recomputed by every reader
    return face;
}

// The closed solid: the spline face, four walls, the back; its shell built from shared
// edges, so no sewing is needed.
inline TopoDS_Solid closed_part(const BSplineSurface& s, double back_w) {
    const TColgp_Array2OfPnt poles = occt_poles(s);
    const Knots ku = distinct_knots(s.knots_u), kv = distinct_knots(s.knots_v);
    const Handle(Geom_BSplineSurface) surface =
        new Geom_BSplineSurface(poles, occt_reals(ku.values), occt_reals(kv.values), occt_ints(ku.mults),
                                occt_ints(kv.mults), BSplineSurface::degree, BSplineSurface::degree);
    const PartEdges e = part_edges(poles, ku, kv, back_w * mm_per_m);
    const TopoDS_Face faces[6] = {
        top_face(surface, e),
        plane_face(gp_Pnt(0, e.y0, 0), gp_Dir(0, -1, 0), e.top_y0, e.up10, e.back_y0, e.up00),
        plane_face(gp_Pnt(0, e.y1, 0), gp_Dir(0, 1, 0), e.top_y1, e.up11, e.back_y1, e.up01),
        plane_face(gp_Pnt(e.x0, 0, 0), gp_Dir(-1, 0, 0), e.top_x0, e.up01, e.back_x0, e.up00),
        plane_face(gp_Pnt(e.x1, 0, 0), gp_Dir(1, 0, 0), e.top_x1, e.up11, e.back_x1, e.up10),
        plane_face(gp_Pnt(0, 0, e.zb), gp_Dir(0, 0, -1), e.back_y0, e.back_x1, e.back_y1, e.back_x0)};
    BRep_Builder builder;
    TopoDS_Shell shell;
    builder.MakeShell(shell);
    for (const TopoDS_Face& f : faces) builder.Add(shell, f);
    shell.Closed(true);
    TopoDS_Solid part;
    builder.MakeSolid(part);
    builder.Add(part, shell);
    BRepLib::OrientClosedSolid(part);
    return part;
}

// The STEP text (AP214) of `part` (millimetres) with the product name `name`; `path`
// only names the file in messages.
inline std::string step_text(const std::filesystem::path& path, const TopoDS_Solid& part, const std::string& name) {
    const std::lock_guard<std::mutex> lock(statics_mutex());
    const Quiet quiet;
    STEPControl_Writer writer;  // registers the STEP statics before they are set below
    Interface_Static::SetCVal("xstep.cascade.unit", "MM");  // the unit of our shape
    Interface_Static::SetCVal("write.step.unit", "MM");     // the unit the file declares
    Interface_Static::SetCVal("write.step.schema", "AP214IS");
    if (writer.Transfer(part, STEPControl_ManifoldSolidBrep) != IFSelect_RetDone)
        throw IoError("cannot write STEP file '" + path.string() + "': OCCT did not translate the solid" +
                      quiet.detail());
    // OCCT names the product after the static write.step.product.name plus a counter
    // ("name 1"); the one PRODUCT entity gets our name as it is instead (OCCT's writer
    // quotes it for the file).
    const Handle(StepData_StepModel) model = writer.Model();
    const Handle(TCollection_HAsciiString) product_name = new TCollection_HAsciiString(name.c_str());
    for (int k = 1; k <= model->NbEntities(); ++k)
        if (const auto product = Handle(StepBasic_Product)::DownCast(model->Value(k)); !product.IsNull()) {
            product->SetId(product_name);
            product->SetName(product_name);
        }
    // The text is made in memory and written by write_file_atomically (io/file.hpp), not
    // by OCCT's own Write: a full disk or a file-size limit then gives the system's reason
    // and the file's name, and never leaves a partial part under the file's name.
    Handle(StepData_Protocol) protocol = Handle(StepData_Protocol)::DownCast(model->Protocol());
    if (protocol.IsNull()) protocol = StepAP214::Protocol();
    StepData_StepWriter step_text(model);
    step_text.SendModel(protocol);
    std::ostringstream text;
    if (!step_text.Print(text))
        throw IoError("cannot write STEP file '" + path.string() + "': OCCT could not print the model" +
                      quiet.detail());
    return text.str();
}

}  // namespace step_detail

// Writes `s` as one closed solid (see the top of this file) to `path`, replacing the file.
// Throws InputError when back_w is not below the spline (or the spline is malformed), and
// IoError naming the file when OCCT cannot build or write the part.
inline void write_step(const std::filesystem::path& path, const BSplineSurface& s, const StepSolid& solid) {
    namespace sd = step_detail;
    sd::check_spline(s);
    // A B-spline lies in the convex hull of its poles, so no point of the surface is lower
    // than the lowest pole: a back face below that cannot touch the top face, and the walls
    // have positive height everywhere. (The true minimum may be a little higher, so a
    // back_w between the two is refused although it would work; the fit's poles hug the
    // surface, so that band is thin.)
    const double lowest = *std::min_element(s.z.begin(), s.z.end());
    if (!std::isfinite(solid.back_w) || !(solid.back_w < lowest))
        throw InputError("STEP export: back_w = " + sd::metres(solid.back_w) +
                         " must lie below the surface's lowest pole at w = " + sd::metres(lowest));
    std::string text;
    try {
        text = sd::step_text(path, sd::closed_part(s, solid.back_w), solid.name);
    } catch (const Standard_Failure& e) {
        throw IoError("cannot write STEP file '" + path.string() + "': OCCT failed building the part (" +
                      e.GetMessageString() + ")");
    }
    write_file_atomically(path, text);
}

// A STEP part read back through OCCT, with the checks and the samplers an exported part is
// judged by. Lengths of the shape are in millimetres (read_step asks OCCT for mm); the
// accessors answer in metres. The samplers are const and may run on several threads at
// once: OCCT 7.6's Geom_BSplineSurface keeps no evaluation cache.
struct StepPart {
    TopoDS_Shape shape;
    TopoDS_Face top_face;                   // the face on a B-spline surface
    Handle(Geom_BSplineSurface) top;        // its surface, as OCCT re-read it (mm)
    double s_min = 0, s_max = 0, t_min = 0, t_max = 0;  // its parameter bounds

    // BRepCheck_Analyzer: topology and geometry consistent (edges on their faces within
    // tolerance, closed wires, …).
    bool is_valid() const { return !shape.IsNull() && BRepCheck_Analyzer(shape).IsValid(); }

    int solid_count() const {
        int n = 0;
        for (TopExp_Explorer x(shape, TopAbs_SOLID); x.More(); x.Next()) ++n;
        return n;
    }

    // Watertight: the shape has faces and every (non-degenerate) edge bounds exactly two
    // of them. A free edge (one face) or a fin (three) makes it false.
    bool closed() const {
        TopTools_IndexedDataMapOfShapeListOfShape faces_of_edge;
        TopExp::MapShapesAndAncestors(shape, TopAbs_EDGE, TopAbs_FACE, faces_of_edge);
        if (faces_of_edge.IsEmpty()) return false;
        for (int k = 1; k <= faces_of_edge.Extent(); ++k) {
            if (BRep_Tool::Degenerated(TopoDS::Edge(faces_of_edge.FindKey(k)))) continue;
            // The list holds a face once per use; a face using an edge twice (a seam) counts twice.
            if (faces_of_edge.FindFromIndex(k).Extent() != 2) return false;
        }
        return true;
    }

    // The enclosed volume in m³ (BRepGProp; negative if the solid were inside out).
    double volume_m3() const {
        GProp_GProps props;
        BRepGProp::VolumeProperties(shape, props);
        const double mm3_per_m3 = step_detail::mm_per_m * step_detail::mm_per_m * step_detail::mm_per_m;
        return props.Mass() / mm3_per_m3;
    }

    // The point of the re-read top surface above (u, v) (surface frame, metres), in
    // metres; (u, v) is clamped to the surface's rectangle. The written parametrisation
    // has x(s, t) = s and y(s, t) = t in mm, so (s, t) = 1000 (u, v) is the answer up to
    // rounding; a few Newton steps on (x, y)(s, t) = 1000 (u, v) make it so for the
    // re-read poles as they are, so the height returned is the file's height at exactly
    // (u, v) even if a reader or another writer moved the poles sideways.
    Vec3d point_m(double u, double v) const { return sample_m(u, v).position; }

    // The unit normal of the re-read top surface at the point point_m(u, v) returns,
    // facing +z (S_s × S_t, flipped if needed).
    Vec3d normal(double u, double v) const { return sample_m(u, v).normal; }

    // Both at once (one search for the parameters): what a tessellation of the part needs.
    PhongVertex sample_m(double u, double v) const {
        double s = 0, t = 0;
        locate(u, v, s, t);
        gp_Pnt p;
        gp_Vec ds, dt;
        top->D1(s, t, p, ds, dt);
        const gp_Vec n = ds.Crossed(dt);
        const Vec3d out = normalize(Vec3d{n.X(), n.Y(), n.Z()});
        return {Vec3d{p.X(), p.Y(), p.Z()} / step_detail::mm_per_m, out.z < 0 ? -out : out};
    }

private:
    gp_Pnt locate(double u, double v, double& s, double& t) const {
        const double x = u * step_detail::mm_per_m, y = v * step_detail::mm_per_m;
        const auto clamp_st = [&] {
            s = std::clamp(s, s_min, s_max);
            t = std::clamp(t, t_min, t_max);
        };
        s = x, t = y;
        clamp_st();
        // Targets outside the rectangle are clamped like BSplineSurface::eval clamps.
        const double tx = std::clamp(x, std::min(s_min, s_max), std::max(s_min, s_max));
        const double ty = std::clamp(y, std::min(t_min, t_max), std::max(t_min, t_max));
        gp_Pnt p;
        gp_Vec ds, dt;
        for (int it = 0; it < 8; ++it) {
            top->D1(s, t, p, ds, dt);
            const double ex = p.X() - tx, ey = p.Y() - ty;
            if (std::abs(ex) <= 1e-10 && std::abs(ey) <= 1e-10) break;  // mm: 0.1 pm
            const double det = ds.X() * dt.Y() - ds.Y() * dt.X();
            if (!(std::abs(det) > 1e-300)) break;
            s -= (dt.Y() * ex - dt.X() * ey) / det;
            t -= (ds.X() * ey - ds.Y() * ex) / det;
            clamp_st();
        }
        return top->Value(s, t);
    }
};

// Reads a STEP file and finds its B-spline top face (the first face whose surface is a
// Geom_BSplineSurface, directly or trimmed). Throws IoError naming the file when it is
// missing, unreadable, holds no shape or no B-spline face.
inline StepPart read_step(const std::filesystem::path& path) {
    const std::string where = "STEP file '" + path.string() + "'";
    std::error_code ec;
    if (!std::filesystem::is_regular_file(path, ec)) throw IoError("cannot read " + where + ": no such file");
    StepPart part;
    try {
        const std::lock_guard<std::mutex> lock(step_detail::statics_mutex());
        const step_detail::Quiet quiet;
        STEPControl_Reader reader;
        Interface_Static::SetCVal("xstep.cascade.unit", "MM");  // the shape's lengths in mm, whatever the file's unit
        if (reader.ReadFile(path.string().c_str()) != IFSelect_RetDone)
            throw IoError("cannot read " + where + ": not a readable STEP file" + quiet.detail());
        if (reader.TransferRoots() < 1) throw IoError("cannot read " + where + ": it holds no shape" + quiet.detail());
        part.shape = reader.OneShape();
    } catch (const Standard_Failure& e) {
        throw IoError("cannot read " + where + ": OCCT failed (" + e.GetMessageString() + ")");
    }
    if (part.shape.IsNull()) throw IoError("cannot read " + where + ": it holds no shape");
    for (TopExp_Explorer x(part.shape, TopAbs_FACE); x.More() && part.top.IsNull(); x.Next()) {
        const TopoDS_Face face = TopoDS::Face(x.Current());
        Handle(Geom_Surface) surface = BRep_Tool::Surface(face);  // with the face's placement applied
        if (const auto trimmed = Handle(Geom_RectangularTrimmedSurface)::DownCast(surface); !trimmed.IsNull())
            surface = trimmed->BasisSurface();
        if (const auto spline = Handle(Geom_BSplineSurface)::DownCast(surface); !spline.IsNull()) {
            part.top_face = face;
            part.top = spline;
        }
    }
    if (part.top.IsNull()) throw IoError("cannot read " + where + ": no face on a B-spline surface");
    part.top->Bounds(part.s_min, part.s_max, part.t_min, part.t_max);
    return part;
}

}  // namespace freeform::io
