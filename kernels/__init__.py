"""NVIDIA Warp kernels of ogscene3d (installed as ``ogscene3d.kernels``). Kernels only: no torch, no I/O."""
