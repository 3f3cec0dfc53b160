"""Gymnasium environments of the bench: HeliSitl/Track-v0 and its vectorised form."""
