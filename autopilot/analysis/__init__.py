"""Offline analyses of the controller (linear loop margins); nothing here runs in flight."""
