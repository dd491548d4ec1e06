// The chunk of items a per-item kernel runs over (the Rust twin is `ChunkUniform`): kernels
// run in chunks small enough for the adapter's storage-binding limit, and every per-item
// binding holds exactly the chunk's items, from index 0.

//#import helpers.wgsl

struct Chunk {
    // The chunk's first item in the whole run (a Gaussian's index in the scene).
    first: u32,
    // Items in the chunk.
    count: u32,
    unused0: u32,
    unused1: u32,
}

@group(1) @binding(0) var<uniform> chunk: Chunk;

// The index within the chunk of this thread's item, for workgroups of 256 threads; valid
// below `chunk.count`.
fn chunk_item(wid: vec3u, nwg: vec3u, lid: u32) -> u32 {
    return flat_index(wid, nwg, lid, 256u);
}
