"""ogscene3d.mapping"""
