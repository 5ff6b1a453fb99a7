// The entry points of the closed-form lighting passes, appended to asg.wgsl and sh.wgsl (each
// of which defines `globals` with its `view_proj`, `materials`, and `shaded`: the radiance, RGBA,
// at a point `world` of material `mat` whose parameters there are `p`).

@vertex
fn vs_main(v: VertexIn) -> VertexOut {
    return surface_vertex(globals.view_proj, v);
}

@fragment
fn fs_main(in: VertexOut, @builtin(front_facing) front: bool) -> @location(0) vec4<f32> {
    let mat = materials[in.material];
    let tc = fragment_coordinates(in.uv, in.uv1);
    if !fragment_drawn(mat, front, tc, in.color.a) {
        discard;
    }
    let p = surface_params(mat, tc, in.normal, in.tangent, in.color, front);
    return shaded(in.world, mat, p);
}

// A blended surface (glTF's BLEND), drawn after the opaque ones back to front without writing
// depth: shaded as fs_main shades, premultiplied by its alpha for the over operator.
@fragment
fn fs_blended(in: VertexOut, @builtin(front_facing) front: bool) -> @location(0) vec4<f32> {
    let mat = materials[in.material];
    let p = blended_params(mat, in, front);
    return premultiplied(shaded(in.world, mat, p).rgb, p.alpha);
}
