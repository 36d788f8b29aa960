"""Files on disk: atomic writes, field checkpoints, run folders, the sample meshes shipped with pymeshlab."""
