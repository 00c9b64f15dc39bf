// touchfem renderer: the deformed surface (Blinn-Phong, two-sided), an optional
// wireframe (line list over the surface edges, pulled slightly towards the eye), and the finger
// and god-object spheres (opaque where visible, ghosted where hidden behind the surface).

struct Camera {
    view_proj: mat4x4<f32>,
    // Eye position (xyz), w: how far wireframe lines are pulled towards the eye (m).
    eye: vec4<f32>,
    // Unit direction towards the light (xyz).
    light_dir: vec4<f32>,
    // Surface colour (linear RGB, a = 1).
    base_color: vec4<f32>,
    // Wireframe colour (linear RGB, a = 1).
    line_color: vec4<f32>,
    // The drawn object's offset in the scene (xyz, m): its vertices are in its own frame.
    // Zero for the spheres, which are given in the scene frame.
    offset: vec4<f32>,
}

@group(0) @binding(0) var<uniform> cam: Camera;

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
    let spec = pow(max(dot(n, h), 0.0), 48.0) * 0.2;
    // Hemisphere ambient: a little brighter facing up (+z).
    let ambient = 0.18 + 0.07 * n.z;
    return color * (ambient + 0.8 * diffuse) + vec3<f32>(spec);
}

struct SurfaceOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) world: vec3<f32>,
    @location(1) normal: vec3<f32>,
}

@vertex
fn vs_surface(@location(0) pos: vec4<f32>, @location(1) normal: vec4<f32>) -> SurfaceOut {
    var out: SurfaceOut;
    let world = pos.xyz + cam.offset.xyz;
    out.clip = cam.view_proj * vec4<f32>(world, 1.0);
    out.world = world;
    out.normal = normal.xyz;
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
    return vec4<f32>(shade(in.world, n, cam.base_color.rgb), 1.0);
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
    return vec4<f32>(shade(in.world, in.normal, in.color.rgb), 1.0);
}

// The hidden parts of the spheres (drawn with depth test "greater"), blended as a ghost.
@fragment
fn fs_sphere_hidden(in: SphereOut) -> @location(0) vec4<f32> {
    return vec4<f32>(shade(in.world, in.normal, in.color.rgb), 0.4);
}
