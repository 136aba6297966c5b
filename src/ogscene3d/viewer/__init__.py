"""ogscene3d.viewer"""
