"""Matches in and out of ctxmatch: hloc and COLMAP export (:mod:`.export`) and OpenCV / kornia interop
(:mod:`.interop`)."""
