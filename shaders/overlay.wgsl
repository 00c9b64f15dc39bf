// touchfem text overlay: a pre-rasterised RGBA image (straight alpha) drawn 1:1 as a
// screen-space quad at a pixel position, blended over the frame.

struct Quad {
    // Top-left corner (xy) and size (zw) of the image, in pixels of the target.
    rect: vec4<f32>,
    // The target's size in pixels (xy).
    target_size: vec4<f32>,
}

@group(0) @binding(0) var<uniform> quad: Quad;
@group(0) @binding(1) var image: texture_2d<f32>;

// A triangle strip of 4 vertices: (0, 0), (1, 0), (0, 1), (1, 1) over the rectangle.
@vertex
fn vs_overlay(@builtin(vertex_index) i: u32) -> @builtin(position) vec4<f32> {
    let corner = vec2<f32>(f32(i & 1u), f32(i >> 1u));
    let px = quad.rect.xy + corner * quad.rect.zw;
    let ndc = vec2<f32>(
        2.0 * px.x / quad.target_size.x - 1.0,
        1.0 - 2.0 * px.y / quad.target_size.y,
    );
    return vec4<f32>(ndc, 0.0, 1.0);
}

// One texel per pixel: no sampler, no filtering.
@fragment
fn fs_overlay(@builtin(position) pos: vec4<f32>) -> @location(0) vec4<f32> {
    let dims = vec2<i32>(textureDimensions(image));
    let p = clamp(vec2<i32>(floor(pos.xy - quad.rect.xy)), vec2<i32>(0), dims - vec2<i32>(1));
    return textureLoad(image, p, 0);
}
