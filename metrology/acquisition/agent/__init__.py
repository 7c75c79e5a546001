"""The agent side of acquisition: no Django here (``gcps agent`` and ``gcps capture`` run on the rig computer).

- :mod:`.patterns`: the codec to project and its projector images;
- :mod:`.cameras`: camera backends behind one small interface (OpenCV, GenICam, virtual rig);
- :mod:`.checks`: per-frame synchronisation and exposure checks, auto-exposure;
- :mod:`.sequencer`: show each pattern, wait for its confirmation and the settle time, grab, check, re-grab;
- :mod:`.client`: the HTTP client of the server's agent protocol (docs/acquisition.md).
"""
