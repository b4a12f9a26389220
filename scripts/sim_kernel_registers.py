"""Registers per thread and local-memory (spill) frame of the MPM's CUDA kernels, without a GPU.

Why: whether a kernel waits on memory depends on how many warps an SM can keep resident, which
its register count decides (65,536 registers per SM; Warp's blocks of 256 threads, or 128). NVRTC (bundled with
warp) compiles for a given architecture without a driver; the counts are read from the cubin's
.nv.info attributes (EIATTR_REGCOUNT, EIATTR_FRAME_SIZE). A frame above 0 means spills to local
memory, or a call stack for the CUDA math library's slow-path helpers (grid_update's 32 B).

Usage:
    python scripts/sim_kernel_registers.py [--arch 90] [--caps 64] [--p2g-caps 128 80] [--column-caps 80]
"""
from __future__ import annotations

import argparse
import re
import struct
import tempfile
from pathlib import Path

REGCOUNT, FRAME_SIZE = 0x2F, 0x11  # EIATTR ids
SVAL = 0x04  # EIFMT: attribute with a value block


def cubin_kernel_info(path: Path) -> dict[str, dict[str, int]]:
    """{symbol: {"regs": n, "frame": bytes}} from the .nv.info sections of a CUDA cubin (ELF64)."""
    b = path.read_bytes()
    shoff = struct.unpack_from("<Q", b, 0x28)[0]
    shentsize, shnum, shstrndx = struct.unpack_from("<HHH", b, 0x3A)
    secs = [struct.unpack_from("<IIQQQQIIQQ", b, shoff + i * shentsize) for i in range(shnum)]

    def cstr(off: int) -> str:
        return b[off:b.index(b"\0", off)].decode()

    names = [cstr(secs[shstrndx][4] + s[0]) for s in secs]
    symtab, strtab = secs[names.index(".symtab")], secs[names.index(".strtab")]
    symbols = [cstr(strtab[4] + struct.unpack_from("<I", b, symtab[4] + 24 * i)[0]) for i in range(symtab[5] // 24)]
    info: dict[str, dict[str, int]] = {}
    for sec, name in zip(secs, names):
        if not name.startswith(".nv.info"):
            continue
        off, end = sec[4], sec[4] + sec[5]
        while off < end:
            fmt, attr, size = struct.unpack_from("<BBH", b, off)
            if fmt != SVAL:  # value-less attributes: 4 bytes
                off += 4
                continue
            if attr in (REGCOUNT, FRAME_SIZE) and size >= 8:
                sym, value = struct.unpack_from("<II", b, off + 4)
                info.setdefault(symbols[sym], {})["regs" if attr == REGCOUNT else "frame"] = value
            off += 4 + size
    return info


def resident_warps(regs: int, block_threads: int) -> int:
    """Warps an sm_90 SM keeps resident for a kernel of `regs` registers per thread in blocks of
    `block_threads` (65,536 registers, allocated per warp in units of 256; at most 64 warps)."""
    if regs <= 0:
        return 0
    per_warp = -(-regs * 32 // 256) * 256
    warps_per_block = block_threads // 32
    return min(64, 65536 // (per_warp * warps_per_block) * warps_per_block)


def compile_and_report(label: str, kernel, arch: int, out_dir: Path) -> None:
    import warp as wp

    paths = wp.compile_aot_module(kernel.module, arch=arch, module_dir=str(out_dir / label), use_ptx=False)
    entry = re.compile(r"(^|_)" + re.escape(kernel.key.split(".")[-1]) + r"_[0-9a-f]{8}_cuda_kernel_forward$")
    for sym, v in cubin_kernel_info(Path(paths[0])).items():
        if entry.search(sym):
            regs = v.get("regs", 0)
            print(f"{label:<28} {regs:>4} registers  spill frame {v.get('frame', 0):>4} B  "
                  f"≤ {resident_warps(regs, 256)} resident warps/SM ({resident_warps(regs, 128)} in blocks of 128)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--arch", type=int, default=90, help="SM architecture (90: H100/H200)")
    parser.add_argument("--caps", type=int, nargs="*", default=[64], help="G2P register caps to try")
    parser.add_argument("--p2g-caps", type=int, nargs="*", default=[128, 80], help="chunked P2G register caps to try")
    parser.add_argument("--column-caps", type=int, nargs="*", default=[80], help="column P2G register caps to try")
    args = parser.parse_args()
    import warp as wp

    wp.config.log_level = wp.LOG_WARNING
    wp.init()
    from pixie_gs.sim import kernels, p2g_column

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        for label, k in [("p2g (atomic)", kernels.p2g), ("p2g_chunked", kernels.p2g_chunked),
                         ("p2g_column", p2g_column.p2g_column), ("p2g_column_carry", p2g_column.p2g_column_carry),
                         ("p2g_slab", p2g_column.p2g_slab), ("p2g_slab_carry", p2g_column.p2g_slab_carry),
                         ("grid_update", kernels.grid_update), ("grid_update_packed", p2g_column.grid_update_packed),
                         ("g2p", kernels.g2p), ("g2p_carry", p2g_column.g2p_carry)]:
            compile_and_report(label, k, args.arch, out)
        for cap in args.caps:
            compile_and_report(f"g2p, cap {cap}", kernels.register_capped(kernels.g2p, cap), args.arch, out)
        for cap in args.p2g_caps:
            compile_and_report(f"p2g_chunked, cap {cap}", kernels.register_capped(kernels.p2g_chunked, cap), args.arch,
                               out)
        for cap in args.column_caps:
            compile_and_report(f"p2g_column, cap {cap}", kernels.register_capped(p2g_column.p2g_column, cap),
                               args.arch, out)


if __name__ == "__main__":
    main()
