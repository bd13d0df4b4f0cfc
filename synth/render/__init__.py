"""Renders of a pile: top-down orthographic observations (:mod:`.ortho`), the ZED-like stereo
pair (:mod:`.stereo`), bark and ground textures (:mod:`.textures`) and preview pictures
(:mod:`.preview`)."""
