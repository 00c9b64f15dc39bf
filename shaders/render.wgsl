// touchfem renderer: the deformed surface (Blinn-Phong; back faces culled, the surface being
// closed and counter-clockwise seen from outside) in one colour or coloured
// by the displacement's magnitude |u| (viridis; |u| is position.w of touchfem::gpu::Vertex,
// written by the deformation pass), an optional wireframe (line list over the surface edges,
// pulled slightly towards the eye), the finger and god-object spheres and the force arrows
// (opaque where visible, ghosted where hidden behind the surface).

struct Camera {
    view_proj: mat4x4<f32>,
    // Eye position (xyz), w: how far wireframe lines are pulled towards the eye (m).
    eye: vec4<f32>,
    // Unit direction towards the light (xyz).
    light_dir: vec4<f32>,
    // Surface colour (linear RGB, a = 1).
    base_color: vec4<f32>,
    // Wireframe colour (linear RGB) and opacity.
    line_color: vec4<f32>,
    // The drawn object's offset in the scene (xyz, m): its vertices are in its own frame.
    // Zero for the spheres, which are given in the scene frame.
    offset: vec4<f32>,
    // x: 1 / the colour map's full scale (1/m): |u| · x in 0..1 runs along VIRIDIS; 0: the
    // surface is base_color.
    colormap: vec4<f32>,
}

@group(0) @binding(0) var<uniform> cam: Camera;

// The displacement colour map, linear RGB at t = i / 255 (touchfem::render's colormap_lut:
// viridis interpolated in sRGB like the legend, then linearised).
@group(0) @binding(1) var<uniform> colormap_lut: array<vec4<f32>, 256>;

// The colour map at t (clamped to 0..1), linear RGB: between two table entries (a uniform read
// costs a software rasteriser far less than nine blends and three pows a pixel).
fn viridis(t: f32) -> vec3<f32> {
    let x = clamp(t, 0.0, 1.0) * 255.0;
    let i = min(u32(x), 254u);
    return mix(colormap_lut[i].rgb, colormap_lut[i + 1u].rgb, x - f32(i));
}

// x^48 by multiplications (a pow per pixel is an exp and a log on a software rasteriser).
fn pow48(x: f32) -> f32 {
    let x3 = x * x * x;
    let x6 = x3 * x3;
    let x12 = x6 * x6;
    let x24 = x12 * x12;
    return x24 * x24;
}

fn shade(world: vec3<f32>, normal: vec3<f32>, color: vec3<f32>) -> vec3<f32> {
    let v = normalize(cam.eye.xyz - world);
    var n = normalize(normal);
    // Two-sided lighting.
    if dot(n, v) < 0.0 {
        n = -n;
    }
    let l = cam.light_dir.xyz;
    let h = normalize(l + v);
    let diffuse = max(dot(n, l), 0.0);
    let spec = pow48(max(dot(n, h), 0.0)) * 0.2;
    // Hemisphere ambient: a little brighter facing up (+z).
    let ambient = 0.18 + 0.07 * n.z;
    return color * (ambient + 0.8 * diffuse) + vec3<f32>(spec);
}

struct SurfaceOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) world: vec3<f32>,
    @location(1) normal: vec3<f32>,
    // |u|, metres.
    @location(2) magnitude: f32,
}

@vertex
fn vs_surface(@location(0) pos: vec4<f32>, @location(1) normal: vec4<f32>) -> SurfaceOut {
    var out: SurfaceOut;
    let world = pos.xyz + cam.offset.xyz;
    out.clip = cam.view_proj * vec4<f32>(world, 1.0);
    out.world = world;
    out.normal = normal.xyz;
    out.magnitude = pos.w;
    return out;
}

// Where the interpolated vertex normal strays far from the facet normal (a crease, e.g. a cube's
// edge, whose vertex normals average two faces) the facet normal takes over, blended smoothly:
// a cube keeps flat faces while smooth meshes and dents shade smoothly.
@fragment
fn fs_surface(in: SurfaceOut) -> @location(0) vec4<f32> {
    let vn = normalize(in.normal);
    var facet = normalize(cross(dpdx(in.world), dpdy(in.world)));
    if dot(facet, vn) < 0.0 {
        facet = -facet;
    }
    let w = smoothstep(0.8, 0.99, dot(facet, vn));
    let n = normalize(mix(facet, vn, w));
    var color = cam.base_color.rgb;
    if cam.colormap.x > 0.0 {
        color = viridis(in.magnitude * cam.colormap.x);
    }
    return vec4<f32>(shade(in.world, n, color), 1.0);
}

// A surface without creases (touchfem::gpu::Deformer::creased is false: at rest every vertex
// normal is within acos(0.99) of its triangles', where fs_surface uses the vertex normal alone):
// the interpolated vertex normal, without the per-pixel facet normal.
@fragment
fn fs_surface_smooth(in: SurfaceOut) -> @location(0) vec4<f32> {
    var color = cam.base_color.rgb;
    if cam.colormap.x > 0.0 {
        color = viridis(in.magnitude * cam.colormap.x);
    }
    return vec4<f32>(shade(in.world, in.normal, color), 1.0);
}

@vertex
fn vs_line(@location(0) pos: vec4<f32>) -> @builtin(position) vec4<f32> {
    let world = pos.xyz + cam.offset.xyz;
    let towards_eye = normalize(cam.eye.xyz - world);
    return cam.view_proj * vec4<f32>(world + towards_eye * cam.eye.w, 1.0);
}

@fragment
fn fs_line() -> @location(0) vec4<f32> {
    return cam.line_color;
}

// A closed slit's line (where a separating cut's faces meet the surface): opaque, the red of
// cut tissue, over the surface colours and the wireframe alike.
@fragment
fn fs_slit() -> @location(0) vec4<f32> {
    return vec4<f32>(0.80, 0.06, 0.04, 1.0);
}

struct SphereOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) world: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) color: vec4<f32>,
}

// Unit-sphere vertex (position = normal) and per-instance centre/radius and colour.
@vertex
fn vs_sphere(
    @location(0) p: vec3<f32>,
    @location(2) center_radius: vec4<f32>,
    @location(3) color: vec4<f32>,
) -> SphereOut {
    var out: SphereOut;
    out.world = center_radius.xyz + p * center_radius.w;
    out.clip = cam.view_proj * vec4<f32>(out.world, 1.0);
    out.normal = p;
    out.color = color;
    return out;
}

@fragment
fn fs_sphere(in: SphereOut) -> @location(0) vec4<f32> {
    // The colour's alpha: the finger is translucent, so the dent it presses shows through.
    return vec4<f32>(shade(in.world, in.normal, in.color.rgb), in.color.a);
}

// The hidden parts of the spheres (drawn with depth test "greater"), blended as a ghost.
@fragment
fn fs_sphere_hidden(in: SphereOut) -> @location(0) vec4<f32> {
    return vec4<f32>(shade(in.world, in.normal, in.color.rgb), 0.4);
}

// A force arrow: a unit arrow along +z (shaft radius 1, a cone head 4 radii long) placed with
// its base at base_len.xyz, `length` = base_len.w, along dir_radius.xyz (unit) with radius
// dir_radius.w. Vertex: (x, y) across, along = a·length + b·head, head = min(4·radius, length);
// its normal in the same frame.
@vertex
fn vs_arrow(
    @location(0) p: vec4<f32>,
    @location(1) local_normal: vec3<f32>,
    @location(2) base_len: vec4<f32>,
    @location(3) dir_radius: vec4<f32>,
    @location(4) color: vec4<f32>,
) -> SphereOut {
    let d = dir_radius.xyz;
    let r = dir_radius.w;
    var helper = vec3<f32>(1.0, 0.0, 0.0);
    if abs(d.x) > 0.9 {
        helper = vec3<f32>(0.0, 1.0, 0.0);
    }
    let e1 = normalize(cross(d, helper));
    let e2 = cross(d, e1);
    let head = min(4.0 * r, base_len.w);
    let along = p.z * base_len.w + p.w * head;
    var out: SphereOut;
    out.world = base_len.xyz + d * along + (e1 * p.x + e2 * p.y) * r;
    out.clip = cam.view_proj * vec4<f32>(out.world, 1.0);
    out.normal = e1 * local_normal.x + e2 * local_normal.y + d * local_normal.z;
    out.color = color;
    return out;
}
