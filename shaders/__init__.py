"""GLSL programs of the renderer, shipped as package data (see README.md beside this file)."""
