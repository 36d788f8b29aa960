"""The built-in deformer plugins, registered through the ``nerfedit.deformers`` entry points exactly as a third
party's would be: ``arap``, ``mesh``, ``cage`` (a folder: mean value and Green coordinates), ``skeleton`` (a folder:
BVH, skinning, bone-heat weights), ``transfer`` (a folder: deformation gradients, correspondence)."""
