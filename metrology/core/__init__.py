"""The measurement core: pure numpy, scipy, OpenCV and open3d, no Django (docs/conventions.md).

A capture becomes points along one path for every codec and model: a codec's decoder gives
projector coordinates, the code-space filters drop unreliable pixels, and the rig's geometric model
triangulates (:mod:`.measure`). Packages and files:

- :mod:`.geometry`: the geometric-model seam, the registry and the models (crossed-axes, pinhole);
- :mod:`.codecs`: any pattern sequence as data, decoded to projector coordinates, rendered;
- :mod:`.measure`: the one measurement entry and the fused gcps-v1 fast path;
- :mod:`.decode`, :mod:`.patterns`: the paper's eleven gcps-v1 patterns and their decoder;
- :mod:`.filters`: the code-space filters of every codec and model;
- :mod:`.blur`, :mod:`.precision`, :mod:`.uncertainty`: camera blur, the phase-noise limit, per-point sigma;
- :mod:`.distortion`: OpenCV's lens distortion, forward and inverse;
- :mod:`.simulate`, :mod:`.scenes`, :mod:`.synthetic`: the virtual rig, its scenes, exact synthetic codes;
- :mod:`.calibrate`, :mod:`.characterize`, :mod:`.acceptance`, :mod:`.sensitivity`: the paper's
  sections 3-5 and VDI/VDE 2634-2;
- :mod:`.procam`: projector-camera calibration from board poses; :mod:`.rig_import`: other
  programs' calibration files as a pinhole rig;
- :mod:`.mesh`: meshes and point clouds of any model; :mod:`.io`: file formats;
- :mod:`.tiling`, :mod:`.allocation`: row tiles on a kept thread pool, glibc's freed-memory reuse;
- :mod:`.compiled`: the compiled (numba) kernels, warmed by workers and the test script;
- :mod:`.option_checks`: the checks every options dataclass shares.
"""
