"""Physical components of the feed axis (electrical, mechanical, sensors) and their assembly."""
