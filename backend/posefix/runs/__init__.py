"""Runs on the web: upload and import, storage, keyframes and exports, revisions, images, who may see what."""
