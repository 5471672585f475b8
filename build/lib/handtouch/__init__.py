"""HandTouch: a thin vision-tactile trainer that proves htdata shards train end to end."""
