"""Built-in field backends (nerf, neus, mesh), registered through the ``nerfedit.fields`` entry points."""
