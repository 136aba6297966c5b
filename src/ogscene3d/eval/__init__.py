"""ogscene3d.eval"""
