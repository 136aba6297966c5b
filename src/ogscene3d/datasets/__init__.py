"""ogscene3d.datasets"""
