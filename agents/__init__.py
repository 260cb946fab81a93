"""Policies that read observations and return actions; no simulator internals."""
