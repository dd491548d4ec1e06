// The splats of a render, read by Gaussian index: the splat array is bound as SPLAT_PARTS
// consecutive parts of `view.parts.x` splats each, so that no binding exceeds the adapter's
// limit. The importing kernel declares `view` and binds the parts at bindings 1 to 4.

//#import helpers.wgsl

@group(0) @binding(1) var<storage, read> splats0: array<Splat>;
@group(0) @binding(2) var<storage, read> splats1: array<Splat>;
@group(0) @binding(3) var<storage, read> splats2: array<Splat>;
@group(0) @binding(4) var<storage, read> splats3: array<Splat>;

fn load_splat(id: u32) -> Splat {
    let part = id / view.parts.x;
    let i = id - part * view.parts.x;
    switch part {
        case 0u: {
            return splats0[i];
        }
        case 1u: {
            return splats1[i];
        }
        case 2u: {
            return splats2[i];
        }
        default: {
            return splats3[i];
        }
    }
}
