"""Editing: edit specs, the Deformer contract, the tet proxy, the lift into it, and the edit job."""
