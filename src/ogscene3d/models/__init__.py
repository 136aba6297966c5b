"""Model export (``ogscene3d models export``) and the models folder manifest read by ``run --models``."""
