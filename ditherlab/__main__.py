from ditherlab.cli import main

main()
