"""Warp-level primitives of the one-warp-per-column step (:mod:`.lanes`): shuffles within a
segment of ``g`` lanes (a power of two dividing 32), a segment max, a segment sum and a whole-warp vote.

On CUDA they are ``shfl.sync`` (PTX) and ``__ballot_sync`` over the full warp (the step keeps
its control flow warp-uniform, so every lane reaches every call). On the CPU they
emulate the warp with Warp's CPU blocks (``wp.config.enable_cpu_blocks``, one fiber per lane,
``block_dim = 32``): a lane writes its value to a static buffer, the block syncs, each lane reads
its source. The CPU runs one block at a time on one thread, so one static buffer per function is
enough. The same kernel text runs on both, so CI checks the lane logic.

``wl`` is the lane's index in its warp (thread index mod 32). Imports Warp only.
"""

import functools
from typing import NamedTuple

import warp as wp

from ...policy.lane_fit import WARP  # lanes of a warp (the butterfly rounds inside one need no barrier)

# One 32-bit shuffle as PTX. Not ``asm volatile`` (Warp's own __shfl_*_sync are): the compiler
# may then schedule the shuffles like other arithmetic, which is safe because the step's control
# flow is warp-uniform. ``mode``: up, down or bfly; ``c`` packs the segment width (PTX ISA, shfl.sync).
_CUDA_SCALAR = {
    "float": """float r; asm("shfl.sync.{mode}.b32 %0, %1, %2, %3, 0xffffffff;" : "=f"(r) : "f"(v), "r"({arg}), "r"(c));
    return r;""",
    # 64-bit values go as two 32-bit halves
    "double": """int lo, hi; asm("mov.b64 {{%0, %1}}, %2;" : "=r"(lo), "=r"(hi) : "d"(v));
    asm("shfl.sync.{mode}.b32 %0, %0, %1, %2, 0xffffffff;" : "+r"(lo) : "r"({arg}), "r"(c));
    asm("shfl.sync.{mode}.b32 %0, %0, %1, %2, 0xffffffff;" : "+r"(hi) : "r"({arg}), "r"(c));
    double r; asm("mov.b64 %0, {{%1, %2}};" : "=d"(r) : "r"(lo), "r"(hi));
    return r;""",
}
_CLAMP = {"up": "((32 - g) << 8)", "down": "(((32 - g) << 8) | 0x1f)", "bfly": "(((32 - g) << 8) | 0x1f)"}


def _shuffle3_snippet(ctype: str, op: str, arg: str, cpu_src: str, name: str) -> str:
    """Native body of a vec3 shuffle: on CUDA three scalar shuffles of ``op``; on the CPU the
    lane reads ``buf[base + src]`` (``src`` a C expression of ``i`` = lane in segment, ``d``, ``g``),
    or keeps its own value where the source lies outside the segment."""
    one = _CUDA_SCALAR[ctype].format(mode=op, arg=arg)
    return f"""
#if defined(__CUDA_ARCH__)
    const int c = {_CLAMP[op]};
    auto sh = [&](const {ctype} v) -> {ctype} {{ {one} }};
    return wp::vec_t<3, {ctype}>(sh(v.c[0]), sh(v.c[1]), sh(v.c[2]));
#else
    static {ctype} {name}[32][3];
    {name}[wl][0] = v.c[0]; {name}[wl][1] = v.c[1]; {name}[wl][2] = v.c[2];
    WP_TILE_SYNC();
    const int base = wl & ~(g - 1);
    const int i = wl - base;
    const int src = {cpu_src};
    wp::vec_t<3, {ctype}> r = v;
    if (src >= 0 && src < g) r = wp::vec_t<3, {ctype}>({name}[base + src][0], {name}[base + src][1], {name}[base + src][2]);
    WP_TILE_SYNC();
    return r;
#endif
"""


def _segment_max_snippet(ctype: str) -> str:
    """Max over the segment's lanes, NaN wins, the same on every lane of the segment."""
    one = _CUDA_SCALAR[ctype].format(mode="bfly", arg="m")
    return f"""
#if defined(__CUDA_ARCH__)
    const int c = {_CLAMP["bfly"]};
    auto sh = [&](const {ctype} v, const int m) -> {ctype} {{ {one} }};
    {ctype} r = v;
    for (int m = 1; m < g; m <<= 1) {{
        const {ctype} y = sh(r, m);
        if (isnan(y) || y > r) r = y;
    }}
    return r;
#else
    static {ctype} wt_segmax[32];
    wt_segmax[wl] = v;
    WP_TILE_SYNC();
    const int base = wl & ~(g - 1);
    {ctype} r = wt_segmax[base];
    for (int t = 1; t < g; ++t) {{
        const {ctype} y = wt_segmax[base + t];
        if (isnan(y) || y > r) r = y;
    }}
    WP_TILE_SYNC();
    return r;
#endif
"""


def _segment_sum3_snippet(ctype: str, name: str) -> str:
    """Sum of a vec3 over the segment's lanes by a butterfly (log2 g rounds of r + partner's r), the
    same bits on every lane of the segment and on both devices (the CPU replays the rounds)."""
    one = _CUDA_SCALAR[ctype].format(mode="bfly", arg="m")
    return f"""
#if defined(__CUDA_ARCH__)
    const int c = {_CLAMP["bfly"]};
    auto sh = [&](const {ctype} v, const int m) -> {ctype} {{ {one} }};
    wp::vec_t<3, {ctype}> r = v;
    for (int m = 1; m < g; m <<= 1) {{
        r = wp::vec_t<3, {ctype}>(r.c[0] + sh(r.c[0], m), r.c[1] + sh(r.c[1], m), r.c[2] + sh(r.c[2], m));
    }}
    return r;
#else
    static {ctype} {name}[32][3];
    const int base = wl & ~(g - 1);
    const int i = wl - base;
    wp::vec_t<3, {ctype}> r = v;
    for (int m = 1; m < g; m <<= 1) {{
        {name}[wl][0] = r.c[0]; {name}[wl][1] = r.c[1]; {name}[wl][2] = r.c[2];
        WP_TILE_SYNC();
        const int src = base + (i ^ m);
        r = wp::vec_t<3, {ctype}>(r.c[0] + {name}[src][0], r.c[1] + {name}[src][1], r.c[2] + {name}[src][2]);
        WP_TILE_SYNC();
    }}
    return r;
#endif
"""


_ANY = """
#if defined(__CUDA_ARCH__)
    return __ballot_sync(0xffffffffu, p) != 0u ? 1 : 0;
#else
    static int wt_vote[32];
    wt_vote[wl] = p;
    WP_TILE_SYNC();
    int r = 0;
    for (int t = 0; t < 32; ++t) r |= (wt_vote[t] != 0);
    WP_TILE_SYNC();
    return r;
#endif
"""


@wp.func_native(_ANY)
def warp_any(p: int, wl: int) -> int:
    """1 if ``p`` is non-zero on any lane of the warp (every lane gets the same answer)."""
    ...


class LaneOps(NamedTuple):
    """The segment primitives of one precision, by name (:func:`make_lane_ops`, :func:`make_block_ops`)."""

    shfl_up3: wp.Function
    shfl_down3: wp.Function
    segment_max: wp.Function
    segment_sum3: wp.Function
    any: wp.Function
    """The vote over the warp (:func:`warp_any`) or the block, ``any(p, wl)``."""
    vec: type
    shfl_updown3: wp.Function
    """``(up, down)`` of a vec3 by d lanes: on one warp the two shuffles, on k warps one exchange (one
    barrier, not two)."""


@functools.cache
def make_lane_ops(real):
    """Shuffles of vec3 over the segment and the segment max, for scalar type ``real``."""
    ctype = "double" if real == wp.float64 else "float"
    vec = wp.types.vector(3, real)
    # Warp keys native functions by name: one name per precision
    tag = "64" if ctype == "double" else "32"

    @wp.func_native(_shuffle3_snippet(ctype, "up", "d", "i - d", f"wt_up{tag}"))
    def shfl_up3(v: vec, d: int, g: int, wl: int) -> vec:
        """The value of lane i - d of the segment (own value where i < d)."""
        ...

    @wp.func_native(_shuffle3_snippet(ctype, "down", "d", "i + d", f"wt_dn{tag}"))
    def shfl_down3(v: vec, d: int, g: int, wl: int) -> vec:
        """The value of lane i + d of the segment (own value where i + d >= g)."""
        ...

    @wp.func
    def shfl_updown3(v: vec, d: int, g: int, wl: int):
        """(:func:`shfl_up3`, :func:`shfl_down3`) of v: two shuffles (k warps: one exchange)."""
        return shfl_up3(v, d, g, wl), shfl_down3(v, d, g, wl)

    @wp.func_native(_segment_max_snippet(ctype))
    def segment_max(v: real, g: int, wl: int) -> real:
        """Max over the segment's g lanes (NaN wins)."""
        ...

    @wp.func_native(_segment_sum3_snippet(ctype, f"wt_sum{tag}"))
    def segment_sum3(v: vec, g: int, wl: int) -> vec:
        """Sum over the segment's g lanes (a butterfly: the same on every lane of the segment)."""
        ...

    return LaneOps(shfl_up3=shfl_up3, shfl_down3=shfl_down3, segment_max=segment_max, segment_sum3=segment_sum3,
                   any=warp_any, vec=vec, shfl_updown3=shfl_updown3)


# --- k warps per column (issue 33 item 3): the same primitives over a CUDA block of G = 32 k lanes ---
#
# A column longer than a warp holds (:func:`warp_tensegrity.policy.lane_fit.lane_map`) runs as one
# block of G threads: lane = thread index in the block (``wl``, 0 .. G-1), and each primitive above
# becomes an exchange through a shared-memory buffer and one barrier (``__syncthreads`` on CUDA,
# ``WP_TILE_SYNC`` between the CPU block's fibers), so the lane code of :mod:`.lane_funcs` and
# :mod:`.lane_rigid` runs unchanged over k warps. Two exceptions spare barriers: a shift up and down of
# one value reads both from one exchange (:func:`shfl_updown3`), and the rounds of a butterfly (segment
# sum and max) whose partner lies in the lane's own warp are warp shuffles on CUDA (no barrier). Two
# buffers alternate, so one barrier per exchange suffices: a lane writes buffer p only after the barrier
# of the next exchange, which every lane reaches after its reads of buffer p. The parity p is each lane's
# own entry of ``wt_bpar`` (the lanes agree: they make the same calls); the vote (``__syncthreads_or``,
# itself a barrier) resets it, and the kernel votes before its first exchange (shared memory starts
# undefined). The step's control flow is block-uniform (these votes), so every thread reaches every
# barrier.
# Hand-written: Warp's tile primitives reduce whole tiles, not a shift by d lanes of a register value.

_STORE = "#if defined(__CUDA_ARCH__)\n    __shared__\n#else\n    static\n#endif\n"
BLOCK_LANES = 512
"""Size of the shared buffers: the most lanes of a block (policy.lane_fit.MAX_COLUMN_LANES, checked
by :func:`make_block_ops`). One size for every G, so each native function has one text per precision."""


def _block_exchange_snippet(ctype: str, name: str) -> str:
    """Rows 0 and 1: the vec3 of lanes ``src`` and ``src2`` of the block (own value where a source
    lies outside 0 .. g-1), from one write and one barrier; g < 0: reset the lane's parity (no
    exchange, no barrier)."""
    own = " ".join(f"r.data[{i}][{k}] = v.c[{k}];" for i in range(2) for k in range(3))
    take = "\n    ".join(f"if ({s} >= 0 && {s} < g) {{ " + " ".join(f"r.data[{i}][{k}] = {name}[p][{s}][{k}];"
                                                            for k in range(3)) + " }"
                          for i, s in enumerate(("src", "src2")))
    return f"""
{_STORE}    {ctype} {name}[2][{BLOCK_LANES}][3];
{_STORE}    unsigned char wt_bpar[{BLOCK_LANES}];
    wp::mat_t<2, 3, {ctype}> r;
    {own}
    if (g < 0) {{ wt_bpar[wl] = 0; return r; }}
    const int p = wt_bpar[wl];
    wt_bpar[wl] = (unsigned char)(p ^ 1);
    {name}[p][wl][0] = v.c[0]; {name}[p][wl][1] = v.c[1]; {name}[p][wl][2] = v.c[2];
    WP_TILE_SYNC();
    {take}
    return r;
"""


def _warp_butterfly_snippet(ctype: str, name: str, op: str) -> str:
    """The first five rounds (partners wl ^ 1 .. wl ^ 16, inside the lane's warp) of a block butterfly,
    ``op`` 'sum3' (r + partner, a vec3) or 'max' (the partner where it is NaN or larger; a scalar):
    on CUDA by warp shuffles, no barrier; on the CPU through a static buffer and the block's barriers.
    The same rounds in the same order as :func:`make_block_ops`' exchanges, so the same bits."""
    one = _CUDA_SCALAR[ctype].format(mode="bfly", arg="m")
    if op == "sum3":
        cuda = f"""wp::vec_t<3, {ctype}> r = v;
    for (int m = 1; m < 32; m <<= 1) {{
        r = wp::vec_t<3, {ctype}>(r.c[0] + sh(r.c[0], m), r.c[1] + sh(r.c[1], m), r.c[2] + sh(r.c[2], m));
    }}
    return r;"""
        cpu = f"""static {ctype} {name}[{BLOCK_LANES}][3];
    wp::vec_t<3, {ctype}> r = v;
    for (int m = 1; m < 32; m <<= 1) {{
        {name}[wl][0] = r.c[0]; {name}[wl][1] = r.c[1]; {name}[wl][2] = r.c[2];
        WP_TILE_SYNC();
        const int src = wl ^ m;
        r = wp::vec_t<3, {ctype}>(r.c[0] + {name}[src][0], r.c[1] + {name}[src][1], r.c[2] + {name}[src][2]);
        WP_TILE_SYNC();
    }}
    return r;"""
    else:
        cuda = f"""{ctype} r = v;
    for (int m = 1; m < 32; m <<= 1) {{
        const {ctype} y = sh(r, m);
        if (isnan(y) || y > r) r = y;
    }}
    return r;"""
        cpu = f"""static {ctype} {name}[{BLOCK_LANES}];
    {ctype} r = v;
    for (int m = 1; m < 32; m <<= 1) {{
        {name}[wl] = r;
        WP_TILE_SYNC();
        const {ctype} y = {name}[wl ^ m];
        if (isnan(y) || y > r) r = y;
        WP_TILE_SYNC();
    }}
    return r;"""
    return f"""
#if defined(__CUDA_ARCH__)
    const int c = {_CLAMP["bfly"].replace("g", "32")};
    auto sh = [&](const {ctype} v, const int m) -> {ctype} {{ {one} }};
    {cuda}
#else
    {cpu}
#endif
"""


_BLOCK_ANY = f"""
#if defined(__CUDA_ARCH__)
    return __syncthreads_or(p) != 0 ? 1 : 0;
#else
    static int wt_bvote[{BLOCK_LANES}];
    wt_bvote[wl] = p;
    WP_TILE_SYNC();
    int r = 0;
    for (int t = 0; t < g; ++t) r |= (wt_bvote[t] != 0);
    WP_TILE_SYNC();
    return r;
#endif
"""


@wp.func_native(_BLOCK_ANY)
def block_any(p: int, g: int, wl: int) -> int:
    """1 if ``p`` is non-zero on any of the block's g lanes (every lane gets the same answer)."""
    ...


@functools.cache
def make_block_ops(real, G: int):
    """:func:`make_lane_ops`' primitives, and the vote ``any``, over a block of G lanes (G = 32 k,
    one column per block); ``g`` must be G and ``wl`` the thread's index in the block."""
    if not (32 < G <= BLOCK_LANES and G & (G - 1) == 0):
        raise ValueError(f"a block of G = {G} lanes: needs a power of two from 64 to {BLOCK_LANES}")
    ctype = "double" if real == wp.float64 else "float"
    vec = wp.types.vector(3, real)

    two = wp.types.matrix((2, 3), real)

    @wp.func_native(_block_exchange_snippet(ctype, f"wt_bx{'64' if ctype == 'double' else '32'}"))
    def exchange2(v: vec, src: int, src2: int, g: int, wl: int) -> two:
        """Rows: the values of lanes ``src`` and ``src2`` (own value where one is outside 0 .. g-1)."""
        ...

    @wp.func
    def exchange3(v: vec, src: int, g: int, wl: int) -> vec:
        """The value of lane ``src`` (own value where src is outside 0 .. g-1)."""
        return exchange2(v, src, -1, g, wl)[0]

    @wp.func
    def vote(p: int, wl: int) -> int:
        """1 if ``p`` is non-zero on any lane of the block; the exchanges' parity back to 0."""
        exchange3(vec(), 0, -1, wl)
        return block_any(p, wp.static(G), wl)

    @wp.func
    def shfl_up3(v: vec, d: int, g: int, wl: int) -> vec:
        """The value of lane wl - d (own value where wl < d)."""
        return exchange3(v, wl - d, g, wl)

    @wp.func
    def shfl_down3(v: vec, d: int, g: int, wl: int) -> vec:
        """The value of lane wl + d (own value where wl + d >= g)."""
        return exchange3(v, wl + d, g, wl)

    @wp.func
    def shfl_updown3(v: vec, d: int, g: int, wl: int):
        """(:func:`shfl_up3`, :func:`shfl_down3`) of v from one exchange: one barrier, not two."""
        r = exchange2(v, wl - d, wl + d, g, wl)
        return r[0], r[1]

    tag = "64" if ctype == "double" else "32"

    @wp.func_native(_warp_butterfly_snippet(ctype, f"wt_bsum{tag}", "sum3"))
    def warp_sum3(v: vec, wl: int) -> vec:
        """The butterfly's rounds inside the warp (partners wl ^ 1 .. wl ^ 16)."""
        ...

    @wp.func_native(_warp_butterfly_snippet(ctype, f"wt_bmax{tag}", "max"))
    def warp_max(v: real, wl: int) -> real:
        """The max butterfly's rounds inside the warp (NaN wins)."""
        ...

    @wp.func
    def segment_sum3(v: vec, g: int, wl: int) -> vec:
        """Sum over the block's g lanes by a butterfly (:func:`make_lane_ops`' order): the rounds
        inside a warp by shuffles, the others (partners 32 lanes and more away) through shared memory."""
        r = warp_sum3(v, wl)
        m = int(WARP)
        while m < g:
            r = r + exchange3(r, wl ^ m, g, wl)
            m = m * 2
        return r

    @wp.func
    def segment_max(v: real, g: int, wl: int) -> real:
        """Max over the block's g lanes (NaN wins), its rounds as :func:`segment_sum3`'s."""
        r = warp_max(v, wl)
        m = int(WARP)
        while m < g:
            y = exchange3(vec(r, r, r), wl ^ m, g, wl)[0]
            if wp.isnan(y) or y > r:
                r = y
            m = m * 2
        return r

    return LaneOps(shfl_up3=shfl_up3, shfl_down3=shfl_down3, segment_max=segment_max, segment_sum3=segment_sum3,
                   any=vote, vec=vec, shfl_updown3=shfl_updown3)
