"""The procedural single-view data: analytic SDFs of CSG programs (``csg``), the shape categories
built from them (``categories``), and the generator that renders and voxelises them into the NMR
ShapeNet layout (``generator``).
"""
