"""Writing rendered frames: PNG (one picture), GIF (Pillow) or MP4 (H.264 through the ffmpeg
binary of the optional `imageio-ffmpeg` package, or an `ffmpeg` on PATH). Atomic, like every
pixie-gs output."""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from ..atomic import atomic_path
from ..errors import InputError

FORMATS = (".png", ".gif", ".mp4")


def output_format(path: str | Path) -> str:
    """The lower-case suffix of an output path, or InputError if it is not a format we write."""
    suffix = Path(path).suffix.lower()
    if suffix not in FORMATS:
        raise InputError(f"output must end in {', '.join(FORMATS)} (got '{suffix or 'no suffix'}')", path)
    return suffix


def ffmpeg_exe() -> str | None:
    """Path of an ffmpeg binary: imageio-ffmpeg's bundled one, else one on PATH, else None."""
    try:
        import imageio_ffmpeg

        return imageio_ffmpeg.get_ffmpeg_exe()
    except Exception:  # not installed, or its binary is missing on this platform
        return shutil.which("ffmpeg")


def save_mp4(frames: list[np.ndarray], path: str | Path, fps: float = 15.0) -> None:
    """Write equally sized uint8 frames (H,W,3) as an H.264 MP4 (yuv420p, plays everywhere)."""
    import subprocess

    exe = ffmpeg_exe()
    if exe is None:
        raise InputError("writing .mp4 needs ffmpeg: `pip install imageio-ffmpeg` (or put ffmpeg on "
                         "PATH), or write a .gif instead", path)
    if not frames:
        raise ValueError("save_mp4 needs at least one frame")
    h, w = frames[0].shape[:2]
    h2, w2 = h + h % 2, w + w % 2  # yuv420p needs even sides
    with atomic_path(path, suffix=".tmp.mp4") as tmp:
        cmd = [exe, "-y", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{w2}x{h2}",
               "-r", f"{fps:g}", "-i", "-", "-an", "-c:v", "libx264", "-pix_fmt", "yuv420p", "-crf", "20",
               "-movflags", "+faststart", str(tmp)]
        proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stderr=subprocess.PIPE)
        try:
            for frame in frames:
                padded = np.full((h2, w2, 3), 255, np.uint8)
                padded[:h, :w] = frame[:, :, :3]
                proc.stdin.write(padded.tobytes())
            proc.stdin.close()
        except BrokenPipeError:
            pass
        err = proc.stderr.read().decode(errors="replace").strip()
        if proc.wait() != 0:
            raise InputError(f"ffmpeg failed: {err.splitlines()[-1] if err else 'unknown error'}", path)


def save_frames(frames: list[np.ndarray], path: str | Path, fps: float = 15.0) -> None:
    """Write frames to `path` by its suffix: .gif / .mp4 animations, .png the first frame."""
    from ..render import save_gif, save_png

    kind = output_format(path)
    if kind == ".png":
        save_png(frames[0], path)
    elif kind == ".gif":
        save_gif(frames, path, fps=fps)
    else:
        save_mp4(frames, path, fps=fps)
