"""Editing: edit specs, the Deformer contract, selections, the tet proxy and the lift into it."""
