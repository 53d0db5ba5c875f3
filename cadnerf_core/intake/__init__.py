"""Stages 1 and 2: photos in (EXIF, orientation, focal length), background removal, crop."""
