"""Rays (the one module that imports embreex) and shafts."""
