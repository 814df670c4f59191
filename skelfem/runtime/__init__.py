"""Process-level machinery: signals as exceptions, MPI ranks that end in step, the JIT cache."""
