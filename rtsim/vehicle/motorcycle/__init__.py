"""The two-wheeler assembly: a motorcycle (or a bicycle) of six bodies in mixed natural coordinates,
built from the kit's parts and a vehicle file."""
