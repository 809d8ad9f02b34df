"""A cloth simulator that drives the render service: a mass-spring sheet (XPBD, numpy) dropped onto
a mannequin of spheres and capsules, and the client that posts every frame to a running service."""

from .cloth import ClothMesh, Springs, sheet
from .proxy import BodyProxy, Capsule, mannequin, sphere
from .solver import ClothSettings, ClothSim, FrameStats

__all__ = ["BodyProxy", "Capsule", "ClothMesh", "ClothSettings", "ClothSim", "FrameStats", "Springs", "mannequin",
           "sheet", "sphere"]
