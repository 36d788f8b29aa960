"""Ray bending: the DeformationField (tet proxy + deformed frames), exact point location and its kernels."""
