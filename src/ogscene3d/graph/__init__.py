"""ogscene3d.graph"""
