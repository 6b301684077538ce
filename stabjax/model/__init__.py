"""The model: the System interface, parameters, the registry of built-in systems, loading a user's file, outcome declarations and rules, tangent dynamics, small unrolled linear algebra."""
