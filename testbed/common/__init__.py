"""What every stage uses: one-line errors and exit codes, files written without following symlinks, strict JSON, a user's code named on the command line."""
