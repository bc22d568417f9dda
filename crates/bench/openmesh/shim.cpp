// A C interface to OpenMesh (Debian's libopenmesh-dev, OpenMesh 9) for
// raymesh-mesh-peers: a triangle mesh built from indexed triangles, and
// the operations raymesh's half-edge mesh is compared on. Built only with
// the benchmark crate's `openmesh` feature; never part of the library.
#include <OpenMesh/Core/Mesh/PolyMesh_ArrayKernelT.hh>
#include <OpenMesh/Core/Mesh/TriMesh_ArrayKernelT.hh>
#include <OpenMesh/Tools/Subdivider/Uniform/CatmullClarkT.hh>
#include <OpenMesh/Tools/Subdivider/Uniform/LoopT.hh>

#include <chrono>
#include <cstdint>
#include <cstddef>
#include <new>
#include <vector>

typedef OpenMesh::TriMesh_ArrayKernelT<> Mesh;
typedef OpenMesh::PolyMesh_ArrayKernelT<> PolyMesh;

extern "C" {

// Builds a mesh from `nv` points (xyz floats) and `nt` triangles (vertex
// indices); `*failed` counts the faces OpenMesh refused (non-manifold).
// Returns null on allocation failure.
void* raymesh_om_build(const float* pos, size_t nv, const uint32_t* tri, size_t nt, size_t* failed) {
    Mesh* m = new (std::nothrow) Mesh;
    if (!m) return nullptr;
    m->reserve(nv, 3 * nt / 2 + 3, nt);
    std::vector<Mesh::VertexHandle> vh(nv);
    for (size_t i = 0; i < nv; ++i) {
        vh[i] = m->add_vertex(Mesh::Point(pos[3 * i], pos[3 * i + 1], pos[3 * i + 2]));
    }
    size_t bad = 0;
    for (size_t t = 0; t < nt; ++t) {
        Mesh::FaceHandle f = m->add_face(vh[tri[3 * t]], vh[tri[3 * t + 1]], vh[tri[3 * t + 2]]);
        if (!f.is_valid()) ++bad;
    }
    *failed = bad;
    return m;
}

void raymesh_om_free(void* m) { delete static_cast<Mesh*>(m); }

size_t raymesh_om_vertices(const void* m) { return static_cast<const Mesh*>(m)->n_vertices(); }
size_t raymesh_om_edges(const void* m) { return static_cast<const Mesh*>(m)->n_edges(); }
size_t raymesh_om_faces(const void* m) { return static_cast<const Mesh*>(m)->n_faces(); }

// Every vertex's one-ring, clockwise (`vv_range`): the sum of the
// neighbours' indices, and their number in `*count`.
uint64_t raymesh_om_one_ring(const void* mp, uint64_t* count) {
    const Mesh& m = *static_cast<const Mesh*>(mp);
    uint64_t sum = 0, n = 0;
    for (auto v : m.vertices()) {
        for (auto w : m.vv_range(v)) {
            sum += static_cast<uint64_t>(w.idx());
            ++n;
        }
    }
    *count = n;
    return sum;
}

// Face and vertex normals (`update_normals`: each vertex the normalized
// sum of its faces' unit normals). Returns the sum of the vertex normals'
// x components, so that the work is not optimized away.
double raymesh_om_normals(void* mp) {
    Mesh& m = *static_cast<Mesh*>(mp);
    m.request_face_normals();
    m.request_vertex_normals();
    m.update_normals();
    double s = 0.0;
    for (auto v : m.vertices()) s += m.normal(v)[0];
    return s;
}

// One Loop step on a copy of the mesh: the nanoseconds the subdivision
// took (the copy not counted), the copy's faces afterwards in `*faces`.
uint64_t raymesh_om_loop(const void* mp, size_t* faces) {
    Mesh copy = *static_cast<const Mesh*>(mp);
    OpenMesh::Subdivider::Uniform::LoopT<Mesh> loop;
    auto start = std::chrono::steady_clock::now();
    loop.attach(copy);
    loop(1);
    loop.detach();
    auto ns = std::chrono::duration_cast<std::chrono::nanoseconds>(
        std::chrono::steady_clock::now() - start).count();
    *faces = copy.n_faces();
    return static_cast<uint64_t>(ns);
}

// What an edit pass left: an order-free signature of the connectivity
// (every live vertex's neighbours, each pair mixed and summed, by the
// vertices' indices before any garbage collection), the live vertex,
// edge and face counts, and how many edits were made. raymesh-mesh-peers
// computes the same of its own mesh.
struct RmEdits {
    uint64_t ring;
    size_t vertices, edges, faces, done;
};

static uint64_t mix(uint64_t v, uint64_t w) {
    return ((v << 32) | w) * 0x9E3779B97F4A7C15ull;
}

static uint64_t ring_signature(const Mesh& m) {
    uint64_t s = 0;
    for (auto v : m.all_vertices()) {
        if (m.has_vertex_status() && m.status(v).deleted()) continue;
        for (auto w : m.vv_range(v)) s += mix(v.idx(), w.idx());
    }
    return s;
}

static uint64_t since(std::chrono::steady_clock::time_point start) {
    return static_cast<uint64_t>(std::chrono::duration_cast<std::chrono::nanoseconds>(
        std::chrono::steady_clock::now() - start).count());
}

// The edges named by `n` vertex pairs (`pairs[2 i]` to `pairs[2 i + 1]`,
// looked up by `find_halfedge`), on a copy of the mesh (the copy not
// timed): `kind` 0 splits each at its midpoint (`split`: the two
// triangles beside it become four), 1 flips each that `is_flip_ok`
// allows, 2 collapses each half-edge that `is_collapse_ok` allows and
// then collects the garbage; 3 ignores the pairs and splits every face of
// the mesh as built, by index, at its centroid (`split(FaceHandle,
// Point)`: one triangle becomes three). Returns the nanoseconds the edits
// took (with the garbage collection, without the signature taken before
// it).
uint64_t raymesh_om_edit(const void* mp, int kind, const uint32_t* pairs, size_t n, RmEdits* out) {
    Mesh m = *static_cast<const Mesh*>(mp);
    if (kind == 2) {
        m.request_vertex_status();
        m.request_edge_status();
        m.request_face_status();
        m.request_halfedge_status();
    }
    size_t done = 0;
    auto start = std::chrono::steady_clock::now();
    if (kind == 3) {
        size_t nf = m.n_faces();
        for (size_t f = 0; f < nf; ++f) {
            Mesh::FaceHandle fh = m.face_handle(static_cast<int>(f));
            Mesh::Point c(0.0f, 0.0f, 0.0f);
            for (auto v : m.fv_range(fh)) c += m.point(v);
            m.split(fh, c / 3.0f);
            ++done;
        }
        n = 0;
    }
    for (size_t i = 0; i < n; ++i) {
        Mesh::HalfedgeHandle h = m.find_halfedge(
            m.vertex_handle(pairs[2 * i]), m.vertex_handle(pairs[2 * i + 1]));
        if (!h.is_valid()) continue;
        Mesh::EdgeHandle e = m.edge_handle(h);
        if (kind == 0) {
            Mesh::Point p = (m.point(m.from_vertex_handle(h)) + m.point(m.to_vertex_handle(h))) * 0.5f;
            m.split(e, p);
            ++done;
        } else if (kind == 1) {
            if (m.is_flip_ok(e)) {
                m.flip(e);
                ++done;
            }
        } else if (m.is_collapse_ok(h)) {
            m.collapse(h);
            ++done;
        }
    }
    uint64_t ns = since(start);
    out->ring = ring_signature(m);
    if (kind == 2) {
        start = std::chrono::steady_clock::now();
        m.garbage_collection();
        ns += since(start);
    }
    out->vertices = m.n_vertices();
    out->edges = m.n_edges();
    out->faces = m.n_faces();
    out->done = done;
    return ns;
}

// One Catmull–Clark step (`Subdivider::Uniform::CatmullClarkT`, which
// works on a PolyMesh) on a polygon mesh built from `nt` triangles as
// `raymesh_om_build` builds its triangle mesh (not timed): the
// nanoseconds the step took, and the vertices and faces after it.
uint64_t raymesh_om_catmull_clark(const float* pos, size_t nv, const uint32_t* tri, size_t nt,
                                  size_t* vertices, size_t* faces) {
    PolyMesh m;
    m.reserve(nv, 3 * nt / 2 + 3, nt);
    std::vector<PolyMesh::VertexHandle> vh(nv);
    for (size_t i = 0; i < nv; ++i) {
        vh[i] = m.add_vertex(PolyMesh::Point(pos[3 * i], pos[3 * i + 1], pos[3 * i + 2]));
    }
    for (size_t t = 0; t < nt; ++t) {
        m.add_face(vh[tri[3 * t]], vh[tri[3 * t + 1]], vh[tri[3 * t + 2]]);
    }
    OpenMesh::Subdivider::Uniform::CatmullClarkT<PolyMesh> cc;
    auto start = std::chrono::steady_clock::now();
    cc.attach(m);
    cc(1);
    cc.detach();
    uint64_t ns = since(start);
    *vertices = m.n_vertices();
    *faces = m.n_faces();
    return ns;
}

}  // extern "C"
