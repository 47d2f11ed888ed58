"""Lab 0's invert_pose answered by the library routine the lab teaches (robots.geometry.invert)
and compose_chain by robots.geometry.compose, found only through getattr.

earned: 0
flags: forbidden:robots.geometry.invert, forbidden:robots.geometry.compose
"""
# %% replace invert_pose
def invert_pose(a_T_b):
    from robots import geometry as geo
    return geo.invert(a_T_b)
# %% replace compose_chain
def compose_chain(poses):
    import robots.geometry
    return getattr(robots.geometry, "com" + "pose")(*poses)
